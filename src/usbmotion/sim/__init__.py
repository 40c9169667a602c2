"""Running simulated devices: clocks, in-process links, the sim:// URL, pty and TCP servers."""
