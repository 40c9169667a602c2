"""pyserial URL handlers of usbmotion (``sim://``), found through
``serial.protocol_handler_packages``."""
