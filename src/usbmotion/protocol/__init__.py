"""The wire protocol: the command table, defined once, and a line codec with no I/O."""
