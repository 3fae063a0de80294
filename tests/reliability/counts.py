"""Counters the reliability suite fills and prints at the end of the test session."""

COUNTS = {"inputs tried": 0, "faults injected": 0, "outputs verified": 0}
