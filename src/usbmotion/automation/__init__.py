"""Automation sequences: polled until Complete or Failure; combinators; homing."""

from usbmotion.automation.homing import (
    Home,
    HomingInputs,
    HomingOutputs,
    LimitSwitchState,
    MoveAxisHome,
    SwitchEdgeReading,
)
from usbmotion.automation.sequence import (
    All,
    AutomationSequence,
    Chain,
    Complete,
    Failure,
    FailureKind,
    Incomplete,
    Transition,
    at_end,
    run_sequence,
)

__all__ = [
    "All",
    "AutomationSequence",
    "Chain",
    "Complete",
    "Failure",
    "FailureKind",
    "Home",
    "HomingInputs",
    "HomingOutputs",
    "Incomplete",
    "LimitSwitchState",
    "MoveAxisHome",
    "SwitchEdgeReading",
    "Transition",
    "at_end",
    "run_sequence",
]
