"""solvers: time-optimal slew solvers (indirect shooting, multiple shooting, continuation)."""
