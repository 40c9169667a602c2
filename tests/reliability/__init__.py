"""Reliability: what the machine does when a host dies, a motor stalls, a switch closes, power
fails mid-write, a counter reaches its end, and after an hour of running."""
