"""The ``usbmotion`` command: a thin layer over the library."""
