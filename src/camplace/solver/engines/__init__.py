"""The engines, one folder each with its compiled kernels beside it."""
