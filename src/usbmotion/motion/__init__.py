"""Motion: G-code to moves, moves to planned segments, segments to setpoints; profiles."""
