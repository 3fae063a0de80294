"""Candidate sampling: chaotic (density-corrected logistic map), uniform and scrambled Sobol."""

from camplace.sampling.candidates import CandidateSet, candidates_from_positions, look_at, make_candidates
from camplace.sampling.samplers import SAMPLERS, sample_positions, sample_unit

__all__ = ["CandidateSet", "candidates_from_positions", "SAMPLERS", "look_at", "make_candidates", "sample_positions", "sample_unit"]
