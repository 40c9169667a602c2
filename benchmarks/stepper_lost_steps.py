"""Lost steps: a load beyond a stepper's pull-out torque mid-move, open and closed loop.

    python benchmarks/stepper_lost_steps.py [--json]

On ``examples/stepper.toml`` (simulated, virtual time): a load is put on one axis's
simulated stepper for 0.3 s, 2 s into a move (call 33 fed to the device; the host knows
nothing of it), at several torques around the NEMA 17's 590 mNm.

- X, open loop (``G1 X150 F1200``, back to X60): the position is the steps issued, so the
  run completes whatever the load; the steps the shaft did not make (the device's truth)
  and the shift the next homing of X makes (its switch edge's latched step count against
  the machine position homing gives it), in microsteps, full steps and mm.
- Z, closed loop (``G1 X120 Y90 Z-60 F1200``): the encoder sees the shaft fall behind on
  the tick it happens: the run's peak following error, and whether Z caught up or faulted
  (call 29's limit), the fault stopping X and Y along their path.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from _common import argument_parser, emit, parse_arguments
from stepper_loads import (
    CLOSED_PROGRAM,
    OPEN_PROGRAM,
    full_steps,
    run_with_load,
    stepper_machine,
)

OPEN_LOADS_MNM = (400.0, 500.0, 550.0, 700.0, 1000.0)
CLOSED_LOADS_MNM = (450.0, 520.0, 560.0, 600.0, 700.0)
ON_S, FOR_S = 2.0, 0.3


def measure() -> dict[str, Any]:
    """Each load's figures, open loop on X and closed loop on Z."""
    rows_open: list[dict[str, Any]] = []
    rows_closed: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as folder:
        config = stepper_machine(Path(folder))
        x = config.axis("X")
        for load in OPEN_LOADS_MNM:
            run = run_with_load(config, OPEN_PROGRAM, axis="X", load_mnm=load, on_s=ON_S,
                                for_s=FOR_S)
            shift = run.rehome_shift if run.rehome_shift is not None else 0
            rows_open.append({
                "load_mnm": load, "completed": run.report.completed,
                "on_s": run.on_s, "off_s": run.off_s,
                "peak_error_microsteps": max(a.max_error_counts for a in run.report.axes
                                             if a.name == "X"),
                "slipped_microsteps": run.slipped_microsteps,
                "rehome_shift_microsteps": shift,
                "rehome_shift_full_steps": full_steps(x, shift),
                "rehome_shift_mm": shift / x.counts_per_mm,
            })
        z = config.axis("Z")
        for load in CLOSED_LOADS_MNM:
            run = run_with_load(config, CLOSED_PROGRAM, axis="Z", load_mnm=load, on_s=ON_S,
                                for_s=FOR_S, rehome=False)
            report = run.report
            peak = next(a for a in report.axes if a.name == "Z")
            fault = report.faults[0] if report.faults else None
            rows_closed.append({
                "load_mnm": load, "completed": report.completed,
                "peak_error_microsteps": peak.max_error_counts,
                "peak_error_mm": peak.max_error_counts / z.counts_per_mm,
                "peak_at_s": peak.max_error_time_s,
                "fault": None if fault is None else f"{fault.axis} {fault.fault}",
                "fault_at_s": None if fault is None else fault.time_s,
                "fault_line": None if fault is None else fault.line,
                "slipped_microsteps": run.slipped_microsteps,
                "stop_planned_mm": report.stop_planned_mm,
                "end_x_mm": report.end_position_mm["X"],
                "end_y_mm": report.end_position_mm["Y"],
            })
    return {"holding_mnm": 590, "load_on_s": ON_S, "load_for_s": FOR_S,
            "following_error_limit_microsteps": config.axis("Z").following_error_limit_counts,
            "open_loop_x": rows_open, "closed_loop_z": rows_closed}


def _text(figures: dict[str, Any]) -> str:
    lines = [f"examples/stepper.toml (NEMA 17, {figures['holding_mnm']} mNm holding), a load for"
             f" {figures['load_for_s']:g} s from {figures['load_on_s']:g} s into the move",
             "X open loop (G1 X150 F1200, back to X60); the next homing of X:",
             "  load mNm  run        peak err  slipped (device)  homing shift: microsteps"
             "  full steps      mm"]
    for row in figures["open_loop_x"]:
        lines.append(
            f"  {row['load_mnm']:8.0f}  {'completed' if row['completed'] else 'STOPPED':9s}"
            f"  {row['peak_error_microsteps']:8d}  {row['slipped_microsteps']:16d}"
            f"  {row['rehome_shift_microsteps']:24d}  {row['rehome_shift_full_steps']:10g}"
            f"  {row['rehome_shift_mm']:7.3f}")
    lines.append(f"Z closed loop (G1 X120 Y90 Z-60 F1200), following-error limit"
                 f" {figures['following_error_limit_microsteps']} microsteps:")
    lines.append("  load mNm  run        Z peak err (microsteps, mm, at s)   fault")
    for row in figures["closed_loop_z"]:
        fault = ("none" if row["fault"] is None else
                 f"{row['fault']} at {row['fault_at_s']:.3f} s, line {row['fault_line']};"
                 f" X and Y stopped on the path at X {row['end_x_mm']:.3f}"
                 f" Y {row['end_y_mm']:.3f}")
        lines.append(
            f"  {row['load_mnm']:8.0f}  {'completed' if row['completed'] else 'STOPPED':9s}"
            f"  {row['peak_error_microsteps']:5d} {row['peak_error_mm']:7.4f} mm"
            f" at {row['peak_at_s']:.3f} s   {fault}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Measure and print the figures."""
    args = parse_arguments(argument_parser(__doc__, runs=1), argv)
    return emit(measure(), _text, as_json=args.json)


if __name__ == "__main__":
    main()
