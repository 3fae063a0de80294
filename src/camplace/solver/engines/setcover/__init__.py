"""The set-cover mode: local search with a Lagrangian bound, then SCIP."""
