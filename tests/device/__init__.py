"""Tests of the simulated USB Motion Device (``usbmotion.device``)."""
