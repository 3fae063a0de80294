"""The matrix-level problem: input checks, what each mode counts, presolve, and set-cover file formats."""
