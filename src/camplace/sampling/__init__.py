"""Candidate sampling: chaotic (density-corrected logistic map), uniform and scrambled Sobol."""

from camplace.sampling.candidates import CandidateSet, look_at, make_candidates
from camplace.sampling.samplers import SAMPLERS, sample_positions, sample_unit

__all__ = ["CandidateSet", "SAMPLERS", "look_at", "make_candidates", "sample_positions", "sample_unit"]
