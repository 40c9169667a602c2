"""The web dashboard: one machine session in a browser (``usbmotion web``).

:mod:`usbmotion.web.dashboard` is what the page can ask of the session, free of any web
framework; :mod:`usbmotion.web.app` serves it (HTTP, the WebSocket, the page). The API is
documented in ``docs/dashboard.md``.
"""
