"""``python -m usbmotion``: the same as the ``usbmotion`` command."""

from usbmotion.cli.main import main

main()
