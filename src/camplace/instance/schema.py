"""Frozen dataclasses of a camplace instance (format v1). Metres, degrees, millimetres as named.

An :class:`Instance` holds resolved geometry (meshes already loaded or generated), so every later
stage works on plain arrays. Poses map a mesh's local coordinates into the world frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

SCHEMA_VERSION = 1
from camplace.geometry import rotation_from_euler_deg  # noqa: E402, F401  (re-exported)
from camplace.instance.lab import PhysicalCamera, TransformConfig  # noqa: E402
from camplace.names import SAMPLERS  # noqa: E402  (one list of the names)


@dataclass(frozen=True)
class Pose:
    """A rigid placement of a mesh: world = R @ local * scale + position.

    Attributes
    ----------
    position_m : (3,) float
        Translation, metres.
    rotation_deg : (3,) float
        Extrinsic X-Y-Z Euler angles, degrees (see :func:`rotation_from_euler_deg`).
    """

    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def rotation(self) -> np.ndarray:
        """(3, 3) float64 world-from-local rotation."""
        return rotation_from_euler_deg(self.rotation_deg)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Map local points to world.

        Parameters
        ----------
        points : (n, 3) float64

        Returns
        -------
        (n, 3) float64
        """
        return np.asarray(points, dtype=np.float64) @ self.rotation().T + np.asarray(self.position_m, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh in its own local frame, metres.

    Attributes
    ----------
    name : str
        Short name used in logs and outputs.
    vertices : (n, 3) float64
    faces : (m, 3) int64
        Vertex indices, counter-clockwise seen from outside (outward normals).
    source : str
        Where it came from: ``file:<path>`` or ``procedural:<shape>``.
    spec : dict
        The instance-file table that produced it (used to write the instance back out).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    source: str = ""
    spec: dict = field(default_factory=dict)

    def transformed(self, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
        """World-space copy of the mesh.

        Returns
        -------
        vertices : (n, 3) float64
        faces : (m, 3) int64
        """
        return pose.apply(self.vertices), self.faces


@dataclass(frozen=True, eq=False)
class Occluder:
    """A static scene mesh (walls, terrain, a rock) placed in the world.

    Attributes
    ----------
    mesh : Mesh
    pose : Pose
    ground : bool
        Terrain: candidate cameras under it (a vertical ray up from the camera hits it) are
        rejected during sampling.
    """

    mesh: Mesh
    pose: Pose = Pose()
    ground: bool = False


@dataclass(frozen=True, eq=False)
class Emitters:
    """Volumetric emitter points of one frame (a coma, a plume): observed without normal or light tests.

    Attributes
    ----------
    positions_m : (e, 3) float64
        World positions, metres.
    weights : (e,) float64
        Relative weights (brightness x density), >= 0, in the same unit as ``Frame.target_weight``.
    source : str
        ``file:<path>`` when read from a CSV file, else ``inline`` or ``procedural``.
    """

    positions_m: np.ndarray
    weights: np.ndarray
    source: str = "inline"

    def __len__(self) -> int:
        return int(self.positions_m.shape[0])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Emitters):
            return NotImplemented
        return bool(np.array_equal(self.positions_m, other.positions_m) and np.array_equal(self.weights, other.weights))

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class Frame:
    """One moment of the event.

    Attributes
    ----------
    target_pose : Pose
        Where the target is in this frame.
    weight : float
        Likelihood P of this frame (>= 0); weights are normalised to sum 1 when points are made.
    time_s : float
        Time stamp, seconds.
    target_weight : float
        Relative weight of the whole target surface in this frame (>= 0), against the emitters'
        weights; a frame's rows sum to its normalised likelihood.
    emitters : Emitters or None
        Volumetric emitter points in this frame.
    occluders : tuple of Occluder
        Occluders present in this frame only (besides the instance's static ones).
    """

    target_pose: Pose
    weight: float = 1.0
    time_s: float = 0.0
    target_weight: float = 1.0
    emitters: Emitters | None = None
    occluders: tuple[Occluder, ...] = ()


@dataclass(frozen=True)
class CameraModel:
    """Pinhole camera intrinsics shared by every candidate (OpenCV convention: x right, y down, z forward).

    Attributes
    ----------
    sensor_width_mm, sensor_height_mm : float
        Physical sensor size.
    focal_length_mm : float
    width_px, height_px : int
        Image resolution.
    near_m, far_m : float
        Observation range along the optical axis (depth), metres.
    """

    sensor_width_mm: float
    sensor_height_mm: float
    focal_length_mm: float
    width_px: int
    height_px: int
    near_m: float = 0.05
    far_m: float = 100.0

    @property
    def fx_px(self) -> float:
        """Focal length in pixels along x."""
        return self.focal_length_mm * self.width_px / self.sensor_width_mm

    @property
    def fy_px(self) -> float:
        """Focal length in pixels along y."""
        return self.focal_length_mm * self.height_px / self.sensor_height_mm

    @property
    def fov_x_deg(self) -> float:
        """Horizontal field of view, 2 * arctan(sensor_width / (2 f)), degrees."""
        return math.degrees(2.0 * math.atan(self.sensor_width_mm / (2.0 * self.focal_length_mm)))

    @property
    def fov_y_deg(self) -> float:
        """Vertical field of view, 2 * arctan(sensor_height / (2 f)), degrees."""
        return math.degrees(2.0 * math.atan(self.sensor_height_mm / (2.0 * self.focal_length_mm)))

    def K(self) -> np.ndarray:
        """(3, 3) float64 intrinsic matrix; pixel centres at integer coordinates, principal point at the image centre."""
        return np.array(
            [
                [self.fx_px, 0.0, (self.width_px - 1) / 2.0],
                [0.0, self.fy_px, (self.height_px - 1) / 2.0],
                [0.0, 0.0, 1.0],
            ]
        )


@dataclass(frozen=True)
class Volume:
    """Axis-aligned box where cameras may stand: min_m < position < max_m (the thesis's V_xyz < V_obs < V_XYZ)."""

    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]

    @property
    def size_m(self) -> np.ndarray:
        """(3,) float64 edge lengths."""
        return np.asarray(self.max_m, dtype=np.float64) - np.asarray(self.min_m, dtype=np.float64)


@dataclass(frozen=True)
class Light:
    """A point light source."""

    position_m: tuple[float, float, float]


QUALITY_MODES = ("binary", "graded")


@dataclass(frozen=True)
class QualitySpec:
    """How the observation quality of a (point, camera) pair is computed.

    Attributes
    ----------
    mode : {"binary", "graded"}
        ``binary``: every observed pair has quality 1. ``graded``: quality = resolution factor x
        incidence factor, in (0, 1].
    required_px_per_m : float
        Resolution (pixels per metre on the target, f_px / distance) at which the resolution factor
        min(1, f_px / distance / required_px_per_m) reaches 1.
    max_incidence_deg : float
        Pairs whose view ray makes a larger angle with the surface normal are not observed; in
        graded mode the incidence factor is cos(angle).
    require_light : bool
        Only lit surface points count: the segment to the light is unblocked and n . l > 0.
    min_target_px : float
        Minimum projected size, pixels (0: none). A camera whose view of a frame's target covers
        fewer pixels (the area of the target's convex hull projected by the camera,
        :func:`camplace.visibility.footprint.target_footprint_px`) observes none of that frame's
        target surface points (emitters are not affected).
    """

    mode: str = "binary"
    required_px_per_m: float = 1000.0
    max_incidence_deg: float = 90.0
    require_light: bool = False
    min_target_px: float = 0.0


@dataclass(frozen=True)
class RunDefaults:
    """Defaults for a run of this instance; the CLI and :func:`camplace.run` may override each."""

    candidates: int = 2000
    points: int = 10000
    sampler: str = "chaotic"
    seed: int = 0
    time_limit_s: float = 60.0
    orientations: int = 1


@dataclass(frozen=True)
class AgentsSpec:
    """Agents that move between the phases of the event (the ``[agents]`` table; see :mod:`camplace.plan`).

    The event's frames are split into consecutive phases; each of the k agents holds one candidate
    pose per phase and travels in a straight line between the starts of consecutive phases.

    Attributes
    ----------
    phases : int or None
        Number of phases of about equal duration (None when ``phase_starts_s`` is given).
    phase_starts_s : tuple of float or None
        Start times of the phases, seconds, strictly increasing (instead of ``phases``).
    speed_m_s : float
        Straight-line travel speed of every agent, m/s (>= 0); re-aiming is free.
    start_positions_m : tuple of (x, y, z) or None
        Where the k agents stand before the event (one row per agent), metres.
    start_time_s : float or None
        When they stand there (default: one phase duration before the first phase starts).
    """

    phases: int | None = None
    phase_starts_s: tuple[float, ...] | None = None
    speed_m_s: float = 0.0
    start_positions_m: tuple[tuple[float, float, float], ...] | None = None
    start_time_s: float | None = None


from camplace.names import ROBUST_OBJECTIVES  # noqa: E402  (one list of the names)


@dataclass(frozen=True)
class RobustSpec:
    """Installation (pose) error the placement is optimised against (the ``[robust]`` table).

    Each candidate gets ``scenarios`` perturbed poses: position ``+ N(0, position_sigma_m^2 I)``
    and rotation ``R @ Exp(w)`` with ``w ~ N(0, rotation_sigma_deg^2 I)`` (a rotation vector in the
    camera frame), the same model as ``[physical]`` (see :mod:`camplace.sampling.perturb`).

    Attributes
    ----------
    position_sigma_m : float
        Standard deviation of the placement error per axis, metres (>= 0).
    rotation_sigma_deg : float
        Standard deviation of each rotation-vector component, degrees (>= 0).
    scenarios : int
        Sampled installations S the objective averages over (>= 1).
    objective : {"mean", "p10"}
        ``mean``: expected objective over the scenarios; ``p10``: the value reached in at least
        90 % of them (an order statistic, see :func:`camplace.robust.p10`).
    eval_scenarios : int
        Fresh installations (another seed) on which the chosen and the nominal systems are
        compared out of sample.
    """

    position_sigma_m: float = 0.0
    rotation_sigma_deg: float = 0.0
    scenarios: int = 32
    objective: str = "mean"
    eval_scenarios: int = 128

    @property
    def zero(self) -> bool:
        """True when there is no pose error (every scenario is the nominal installation)."""
        return self.position_sigma_m == 0.0 and self.rotation_sigma_deg == 0.0


@dataclass(frozen=True, eq=False)
class Instance:
    """A complete camera-placement problem.

    Attributes
    ----------
    name : str
    k : int
        Number of cameras to place.
    camera : CameraModel
    volume : Volume
    light : Light
    target : Mesh
        The observed object, in its local frame; each frame places it with its ``target_pose``.
    occluders : tuple of Occluder
        Static scene geometry. The target also occludes.
    frames : tuple of Frame
        At least one.
    defaults : RunDefaults
    quality : QualitySpec
    physical : PhysicalCamera or None
        The parsed ``[physical]`` table (None when absent): the emulated physical camera used by
        validation when there are no photographs (see :mod:`camplace.validation.physical`).
    robust : RobustSpec or None
        The ``[robust]`` table (None when absent): pose error the placement is optimised against.
    transform : TransformConfig or None
        The parsed ``[transform]`` table (None when absent): simulation-to-lab coordinate transform
        used by ``camplace export`` (see :mod:`camplace.validation.transform`).
    agents : AgentsSpec or None
        The ``[agents]`` table: agents that move between phases of the event (``camplace plan``).
    source : str
        The file (or ``builtin:<name>``) this instance was read from; used in error messages.
    warnings : tuple of str
        What reading it warned about (``"target: the mesh is not watertight ..."``), one line each;
        a run records them in ``solution.json``'s ``warnings``.
    """

    name: str
    k: int
    camera: CameraModel
    volume: Volume
    light: Light
    target: Mesh
    occluders: tuple[Occluder, ...]
    frames: tuple[Frame, ...]
    defaults: RunDefaults = RunDefaults()
    source: str = ""
    quality: QualitySpec = QualitySpec()
    physical: PhysicalCamera | None = None
    transform: TransformConfig | None = None
    agents: AgentsSpec | None = None
    robust: RobustSpec | None = None
    warnings: tuple[str, ...] = ()

    def frame_weights(self) -> np.ndarray:
        """(n_frames,) float64 frame likelihoods normalised to sum 1 (uniform if all are 0)."""
        w = np.array([f.weight for f in self.frames], dtype=np.float64)
        s = w.sum()
        return w / s if s > 0 else np.full(len(w), 1.0 / len(w))

    def target_world(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """World-space target mesh in ``frame``.

        Returns
        -------
        vertices : (n, 3) float64
        faces : (m, 3) int64
        """
        return self.target.transformed(self.frames[frame].target_pose)

    def occluders_world(self, frame: int | None = None) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """World-space occluders as (name, vertices (n, 3) float64, faces (m, 3) int64).

        The static ones, plus those of ``frame`` when a frame is given (the target excluded).
        """
        occ = list(self.occluders)
        if frame is not None:
            occ += list(self.frames[frame].occluders)
        return [(o.mesh.name, *o.mesh.transformed(o.pose)) for o in occ]

    def target_centre(self, frame: int) -> np.ndarray:
        """(3,) float64 centre of the target's bounding box in ``frame``."""
        v, _ = self.target_world(frame)
        return (v.min(axis=0) + v.max(axis=0)) / 2.0
