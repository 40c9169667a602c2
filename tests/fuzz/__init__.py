"""Fuzzing of the two interpreters that take untrusted input: the device's (bytes from USB)
and the G-code interpreter (a user's file).

``make test`` runs a few hundred examples per property; ``make fuzz`` sets
``USBMOTION_FUZZ_EXAMPLES`` to run 100,000 or more.
"""
