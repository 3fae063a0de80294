"""The names a user can choose from, in one place (argparse ``choices`` and the input checks read these).

Imports nothing, so the command line can build its parser without loading numpy or the stages.
"""

from __future__ import annotations

#: Formulations of :func:`camplace.solver.solve`.
MODES: tuple[str, ...] = ("maxcover", "quality", "multiview", "setcover")
#: The modes that enforce a camera team's constraints (:class:`camplace.solver.problem.team.TeamConstraints`).
TEAM_MODES: tuple[str, ...] = ("maxcover", "quality", "multiview", "setcover")
#: Solver engines a user may ask for (``auto`` chooses per problem).
ENGINES: tuple[str, ...] = ("auto", "exact", "mip", "cpsat")
#: Engines of the ``setcover`` verb (the exact bitset engines do not minimise).
SETCOVER_ENGINES: tuple[str, ...] = ("auto", "mip", "cpsat")
#: Candidate position samplers (:func:`camplace.sampling.sample_positions`).
SAMPLERS: tuple[str, ...] = ("chaotic", "uniform", "sobol")
#: Row weightings over the event's frames (:func:`camplace.pipeline.event_weights`).
EVENT_MODES: tuple[str, ...] = ("all", "peak")
#: Robust objectives over sampled installations (``[robust] objective``, ``--robust-objective``).
ROBUST_OBJECTIVES: tuple[str, ...] = ("mean", "p10")
#: Formats of ``camplace export --format``: the lab placement (``placement.{frame}.csv`` / ``.json``)
#: and the camera files (:mod:`camplace.report.export`).
EXPORT_FORMATS: tuple[str, ...] = ("placement", "json", "csv", "colmap", "glb")
#: The camera-file formats (``--format all``), written in the simulation frame.
CAMERA_FORMATS: tuple[str, ...] = ("json", "csv", "colmap", "glb")
#: Coordinate frames of ``camplace export --frame``.
EXPORT_FRAMES: tuple[str, ...] = ("physical", "simulation")
