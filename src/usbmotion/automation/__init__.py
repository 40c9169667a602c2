"""Automation sequences: polled until Complete or Fault; combinators; homing."""
