"""Support code shared by the engines: the deadline, the memory budget, the best-first frontier, greedy
heuristics and the row-bitset kernels."""
