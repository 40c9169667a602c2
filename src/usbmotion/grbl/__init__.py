"""The grbl 1.1h protocol front: existing G-code senders (cncjs, Universal G-code Sender,
Candle, grbl-streamer) drive a usbmotion machine session as if it were grbl.

- :mod:`~usbmotion.grbl.interface`: :class:`GrblMachine`, what the front needs of a machine
  session (one adapter implements it on the real one);
- :mod:`~usbmotion.grbl.protocol`: :class:`GrblProtocol`, the front itself, sans I/O;
- :mod:`~usbmotion.grbl.lines`, :mod:`~usbmotion.grbl.reports`, :mod:`~usbmotion.grbl.codes`:
  its pre-parser and jog parser, its message texts, grbl's error and alarm numbers;
- :mod:`~usbmotion.grbl.server`: one session served on a pseudo-terminal or a TCP port.
"""

from usbmotion.grbl.interface import (
    Admission,
    AxisSettings,
    Fault,
    GrblMachine,
    JogMove,
    MachineSettings,
    MachineStatus,
    ModalState,
    MotionState,
    Rejected,
    SubmitResult,
    Taken,
    WorkOffsets,
)
from usbmotion.grbl.protocol import GrblProtocol

__all__ = [
    "Admission",
    "AxisSettings",
    "Fault",
    "GrblMachine",
    "GrblProtocol",
    "JogMove",
    "MachineSettings",
    "MachineStatus",
    "ModalState",
    "MotionState",
    "Rejected",
    "SubmitResult",
    "Taken",
    "WorkOffsets",
]
