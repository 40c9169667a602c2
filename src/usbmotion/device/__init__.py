"""The device firmware: core0 (commands), core1 (servo loop), motor, flash."""
