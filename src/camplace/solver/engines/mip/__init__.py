"""OR-Tools models: the linear-model backend (SCIP, CP-SAT), the mode models, the max-coverage MIP and CP-SAT engines."""
