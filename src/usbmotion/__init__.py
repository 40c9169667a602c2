"""usbmotion: closed-loop DC servo motion over USB serial, device firmware and host library."""

__version__ = "0.1.0"
