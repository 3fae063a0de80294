"""The engines for 4 < k <= 8: Lagrangian bound, perturbed local search, exact residual search."""
