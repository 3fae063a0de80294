"""The exact quality engines: the quantised tree, the min-Gram triple engine, and their portfolio."""
