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
    """A pinhole camera model (OpenCV convention: x right, y down, z forward).

    The old single ``[camera]`` table is one model shared by every candidate; a team's
    ``[[cameras]]`` tables are one model each (:class:`Team`).

    Attributes
    ----------
    sensor_width_mm, sensor_height_mm : float
        Physical sensor size.
    focal_length_mm : float
    width_px, height_px : int
        Image resolution.
    near_m, far_m : float
        Observation range along the optical axis (depth), metres.
    name : str
        The model's name (unique in a team; ``camera`` for the single ``[camera]``).
    cost : float
        Price of one camera of this model (>= 0; any currency, the unit of ``[team] budget``).
    min_count, max_count : int, int or None
        How many cameras of this model the team must hold at least / may hold at most
        (None: no upper limit). Parsed and validated here; enforced by the solver (:class:`camplace.solver.problem.team.TeamConstraints`).
    """

    sensor_width_mm: float
    sensor_height_mm: float
    focal_length_mm: float
    width_px: int
    height_px: int
    near_m: float = 0.05
    far_m: float = 100.0
    name: str = "camera"
    cost: float = 1.0
    min_count: int = 0
    max_count: int | None = None

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


def _box_contains(min_m, max_m, points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return np.all((p > np.asarray(min_m, dtype=np.float64)) & (p < np.asarray(max_m, dtype=np.float64)), axis=1)


@dataclass(frozen=True)
class Volume:
    """Axis-aligned box where cameras may stand: min_m < position < max_m (the thesis's V_xyz < V_obs < V_XYZ).

    Attributes
    ----------
    min_m, max_m : (3,) float
        Corners, metres.
    models : tuple of str
        Camera models that may stand in it (a team's ``[[volumes]]``); empty: every model.
    share : float
        Relative share of the sampled positions drawn in it (> 0; default 1 per region).
    """

    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]
    models: tuple[str, ...] = ()
    share: float = 1.0

    @property
    def size_m(self) -> np.ndarray:
        """(3,) float64 edge lengths."""
        return np.asarray(self.max_m, dtype=np.float64) - np.asarray(self.min_m, dtype=np.float64)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: points strictly inside the box (points (n, 3) float64, metres)."""
        return _box_contains(self.min_m, self.max_m, points)

    def allows(self, model: str) -> bool:
        """Whether camera model ``model`` may stand here."""
        return not self.models or model in self.models


@dataclass(frozen=True, eq=False)
class Mount:
    """A surface cameras may be mounted on (a wall, a mast): positions are sampled on its triangles.

    Attributes
    ----------
    mesh : Mesh
        In its local frame.
    pose : Pose
        Places it in the world.
    models : tuple of str
        Camera models that may be mounted on it; empty: every model.
    offset_m : float
        The camera centre stands this far off the surface along the triangle's normal (>= 0).
    share : float
        Relative share of the sampled positions drawn on it (> 0).
    """

    mesh: Mesh
    pose: Pose = Pose()
    models: tuple[str, ...] = ()
    offset_m: float = 0.05
    share: float = 1.0

    def world(self) -> tuple[np.ndarray, np.ndarray]:
        """World-space (vertices (n, 3) float64, faces (m, 3) int64)."""
        return self.mesh.transformed(self.pose)

    def allows(self, model: str) -> bool:
        """Whether camera model ``model`` may be mounted here."""
        return not self.models or model in self.models


def _solid_angle_sum(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n,) generalised winding number of a triangle mesh at the points (1 inside a closed outward mesh, 0 outside).

    Van Oosterom and Strackee's solid angle of each triangle, summed, over 4 pi.
    """
    tri = vertices[faces]  # (m, 3, 3)
    out = np.zeros(len(points))
    for s in range(0, len(points), 256):
        a = tri[None, :, 0, :] - points[s:s + 256, None, :]
        b = tri[None, :, 1, :] - points[s:s + 256, None, :]
        c = tri[None, :, 2, :] - points[s:s + 256, None, :]
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        det = np.einsum("pmi,pmi->pm", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("pmi,pmi->pm", a, b) * lc + np.einsum("pmi,pmi->pm", a, c) * lb
               + np.einsum("pmi,pmi->pm", b, c) * la)
        out[s:s + 256] = 2.0 * np.arctan2(det, den).sum(axis=1) / (4.0 * np.pi)
    return out


@dataclass(frozen=True, eq=False)
class KeepOut:
    """A region no camera may stand in: a box (``box``) or a closed mesh (``mesh`` placed by ``pose``)."""

    box: Volume | None = None
    mesh: Mesh | None = None
    pose: Pose = Pose()

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: points inside the keep-out (points (n, 3) float64, metres).

        For a mesh: the generalised winding number is above 1/2 (exact inside a closed mesh).
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if self.box is not None:
            return self.box.contains(p)
        v, f = self.mesh.transformed(self.pose)  # type: ignore[union-attr]
        inside = np.zeros(len(p), dtype=bool)
        near = _box_contains(v.min(axis=0) - 1e-9, v.max(axis=0) + 1e-9, p)
        if near.any():
            inside[near] = np.abs(_solid_angle_sum(v, f, p[near])) > 0.5
        return inside

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(3,), (3,) float64 axis-aligned bounding box, metres."""
        if self.box is not None:
            return np.asarray(self.box.min_m, dtype=np.float64), np.asarray(self.box.max_m, dtype=np.float64)
        v, _ = self.mesh.transformed(self.pose)  # type: ignore[union-attr]
        return v.min(axis=0), v.max(axis=0)


@dataclass(frozen=True)
class Zone:
    """A named box region with camera quotas (``[[zones]]``); enforced by the solver (every mode).

    Attributes
    ----------
    name : str
    min_m, max_m : (3,) float
        Corners, metres; a camera is in the zone when its centre is strictly inside.
    min_cameras : int
        Cameras the team must place in it at least.
    max_cameras : int or None
        At most (None: no limit).
    """

    name: str
    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]
    min_cameras: int = 0
    max_cameras: int | None = None

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: points strictly inside the zone's box."""
        return _box_contains(self.min_m, self.max_m, points)


@dataclass(frozen=True, eq=False)
class Team:
    """A mixed camera team: its models, where each may stand, a budget and zone quotas.

    Present (``Instance.team``) when the file has any of ``[[cameras]]``, ``[[volumes]]``,
    ``[[mounts]]``, ``[[keepouts]]``, ``[team]`` or ``[[zones]]``; an old file with one
    ``[camera]`` and one ``[volume]`` has none and runs exactly as before.

    Attributes
    ----------
    models : tuple of CameraModel
        At least one; names unique. Column ``model`` indices refer to this order.
    volumes : tuple of Volume
        Boxes cameras may stand in (each for some models or all).
    mounts : tuple of Mount
        Surfaces cameras may be mounted on.
    keepouts : tuple of KeepOut
        Where no camera may stand (applies to every model).
    zones : tuple of Zone
    budget : float or None
        Largest total cost of the team (None: no budget).
    """

    models: tuple[CameraModel, ...]
    volumes: tuple[Volume, ...] = ()
    mounts: tuple[Mount, ...] = ()
    keepouts: tuple[KeepOut, ...] = ()
    zones: tuple[Zone, ...] = ()
    budget: float | None = None

    @property
    def model_names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.models)

    def in_keepout(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: points inside any keep-out."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.zeros(len(p), dtype=bool)
        for k in self.keepouts:
            out |= k.contains(p)
        return out

    def allowed_models(self, points: np.ndarray, mount: np.ndarray | None = None) -> np.ndarray:
        """(n, n_models) bool: which models may stand at each point.

        A model may stand at a point inside one of its volumes, or at a point sampled on one of
        its mounts (``mount[i]`` is the index of the mount point i was sampled on, -1 for none),
        and never inside a keep-out.
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.zeros((len(p), len(self.models)), dtype=bool)
        for v in self.volumes:
            inside = v.contains(p)
            for j, m in enumerate(self.models):
                if v.allows(m.name):
                    out[:, j] |= inside
        if mount is not None:
            mount = np.asarray(mount)
            for r, mt in enumerate(self.mounts):
                on = mount == r
                for j, m in enumerate(self.models):
                    if mt.allows(m.name):
                        out[:, j] |= on
        out[self.in_keepout(p)] = False
        return out

    def zone_membership(self, points: np.ndarray) -> np.ndarray:
        """(n, n_zones) bool: whether each point lies in each zone."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return np.column_stack([z.contains(p) for z in self.zones]) if self.zones else np.zeros((len(p), 0), dtype=bool)

    def record(self) -> dict:
        """JSON-ready summary: models (name, cost, min_count, max_count), budget, zones."""
        return {
            "models": [{"name": m.name, "cost": m.cost, "min_count": m.min_count, "max_count": m.max_count} for m in self.models],
            "budget": self.budget,
            "zones": [{"name": z.name, "min_cameras": z.min_cameras, "max_cameras": z.max_cameras} for z in self.zones],
        }


@dataclass(frozen=True)
class Light:
    """A point light source."""

    position_m: tuple[float, float, float]


QUALITY_MODES = ("binary", "graded")
QUALITY_PRECISIONS = ("byte", "float32")


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
    precision : {"byte", "float32"}
        How a graded matrix is kept: ``byte`` quantises each quality to a byte (value ``q / 255``,
        within 1 / 510 of the float value; :mod:`camplace.visibility.qbytes`), ``float32`` keeps the
        float values (8 bytes an observed pair instead of 1 byte a cell). Binary matrices ignore it.
    """

    mode: str = "binary"
    required_px_per_m: float = 1000.0
    max_incidence_deg: float = 90.0
    require_light: bool = False
    min_target_px: float = 0.0
    precision: str = "byte"


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
    team : Team or None
        A mixed team (``[[cameras]]``, ``[[volumes]]``, ...; see :class:`Team`); None for the old
        single ``[camera]`` and ``[volume]``. With a team, ``camera`` is its first model and
        ``volume`` the bounding box of every region cameras may stand in.
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
    team: Team | None = None

    @property
    def cameras(self) -> tuple[CameraModel, ...]:
        """The camera models: the team's, else the single ``camera``. Column ``model`` indices refer to it."""
        return self.team.models if self.team is not None else (self.camera,)

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
