"""Exact engines for camera teams (issue 31): enumeration of the feasible teams."""
