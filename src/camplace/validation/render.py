"""A small Embree ray-casting renderer: what each chosen camera should see.

Per pixel (u, v) a ray leaves the camera centre along ``R K^-1 [u, v, 1]`` (undistorted first when
the camera has lens distortion; OpenCV axes, R world-from-camera). At the first hit:

    I = albedo * light_intensity * max(0, n . l) * lit + ambient

with ``n`` the flat (face) normal turned towards the camera, ``l`` the unit vector to the point
light, and ``lit`` 0 when the segment from the hit point to the light crosses any triangle (hard
shadows), else 1. The light has no distance fall-off (irradiance is independent of distance, so
images do not depend on an arbitrary light power). A ray that hits nothing gets ``background``.
The target's pixels (first hit on the target) form the predicted target mask.

Volumetric emitters (coma or plume particles) are added as glow splats on top: each emitter is a
small glowing ball of radius ``r`` with radiance ``brightness``; it draws a Gaussian of
``sigma = fx r / z`` pixels and peak ``brightness`` (for ``sigma`` below ``min_sigma_px`` the
splat keeps ``min_sigma_px`` and its peak is lowered to conserve flux), behind any surface closer
to the camera than the emitter (per-pixel depth test). Glow is not part of the target mask.

Images are linear float32 radiance; :func:`write_png` quantises them (8 or 16 bit, clipped to [0, 1]).
"""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from camplace._cores import thread_count
from camplace._io import write_bytes_atomic
from camplace.errors import CamplaceError
from camplace.validation.cameras import CameraView

log = logging.getLogger(__name__)

__all__ = [
    "RenderSettings",
    "GlowEmitters",
    "RenderScene",
    "RenderResult",
    "render_view",
    "scene_for_frame",
    "target_scene",
    "write_png",
    "write_mask_png",
    "read_image",
    "as_glow",
    "add_glow",
    "quantise",
]

LABEL_NONE = -1
LABEL_OCCLUDER = 0
LABEL_TARGET = 1


@dataclass(frozen=True)
class RenderSettings:
    """Shading constants of the renderer (linear image units: 1.0 is white).

    Attributes
    ----------
    albedo_target : float
        Lambertian albedo of the target.
    albedo_occluder : float
        Lambertian albedo of the occluders (walls, terrain).
    light_intensity : float
        Irradiance scale of the point light.
    ambient : float
        Added to every surface pixel (lit or not).
    background : float
        Value of pixels whose ray hits nothing.
    shadows : bool
        Cast shadow rays to the light.
    emitter_radius_m : float
        Glow radius of emitters given without their own radius (e.g. the instance's frame emitters).
    emitter_gain : float
        Brightness per unit emitter weight for such emitters.
    min_sigma_px : float
        Smallest glow splat width, pixels.
    """

    albedo_target: float = 0.8
    albedo_occluder: float = 0.5
    light_intensity: float = 1.0
    ambient: float = 0.05
    background: float = 0.0
    shadows: bool = True
    emitter_radius_m: float = 0.01
    emitter_gain: float = 1.0
    min_sigma_px: float = 0.5

    def with_ambient(self, ambient: float) -> "RenderSettings":
        """A copy with another ambient term."""
        from dataclasses import replace

        return replace(self, ambient=float(ambient))


@dataclass(frozen=True, eq=False)
class GlowEmitters:
    """Volumetric emitters drawn as additive glow splats.

    Attributes
    ----------
    positions_m : (e, 3) float64
        World positions.
    brightness : (e,) float64
        Radiance of each emitter (peak of its splat), linear image units.
    radius_m : (e,) float64
        Glow radius of each emitter, metres.
    """

    positions_m: np.ndarray
    brightness: np.ndarray
    radius_m: np.ndarray

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions_m, dtype=np.float64).reshape(-1, 3)
        b = np.broadcast_to(np.asarray(self.brightness, dtype=np.float64), (len(pos),)).copy()
        r = np.broadcast_to(np.asarray(self.radius_m, dtype=np.float64), (len(pos),)).copy()
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(b)) and np.all(np.isfinite(r))):
            raise CamplaceError("emitters: positions, brightness and radius must be finite")
        if np.any(b < 0) or np.any(r <= 0):
            raise CamplaceError("emitters: brightness must be >= 0 and radius_m > 0")
        object.__setattr__(self, "positions_m", pos)
        object.__setattr__(self, "brightness", b)
        object.__setattr__(self, "radius_m", r)

    def __len__(self) -> int:
        return int(self.positions_m.shape[0])

    @classmethod
    def from_pairs(cls, pairs: Sequence[tuple[Sequence[float], float]], radius_m: float = 0.01) -> "GlowEmitters":
        """From a list of ``(position, brightness)`` pairs with one radius."""
        if not pairs:
            return cls(np.zeros((0, 3)), np.zeros(0), np.zeros(0))
        pos = np.array([p for p, _ in pairs], dtype=np.float64)
        return cls(pos, np.array([b for _, b in pairs], dtype=np.float64), radius_m)

    @classmethod
    def load_csv(cls, path: str | Path, radius_m: float = 0.01) -> "GlowEmitters":
        """Read ``x,y,z,brightness[,radius_m]`` rows (one header line)."""
        path = Path(path)
        try:
            data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=np.float64)
        except (OSError, ValueError) as exc:
            raise CamplaceError(f"{path}: cannot read emitters as CSV rows x,y,z,brightness[,radius_m] after a header ({exc})") from None
        if data.shape[1] not in (4, 5):
            raise CamplaceError(f"{path}: emitters need 4 or 5 columns (x,y,z,brightness[,radius_m]), got {data.shape[1]}")
        return cls(data[:, :3], data[:, 3], data[:, 4] if data.shape[1] == 5 else radius_m)


def as_glow(emitters: Any, settings: RenderSettings) -> GlowEmitters | None:
    """Normalise an emitters argument: GlowEmitters, the instance's ``Emitters`` (positions_m, weights), a list of (position, brightness), or None."""
    if emitters is None:
        return None
    if isinstance(emitters, GlowEmitters):
        return emitters
    if hasattr(emitters, "positions_m") and hasattr(emitters, "weights"):
        return GlowEmitters(emitters.positions_m, settings.emitter_gain * np.asarray(emitters.weights, dtype=np.float64), settings.emitter_radius_m)
    return GlowEmitters.from_pairs(list(emitters), settings.emitter_radius_m)


@dataclass(frozen=True, eq=False)
class RenderScene:
    """Triangles to render, with a label and albedo per triangle and the light.

    Build it with :meth:`build`, :func:`scene_for_frame` or :func:`target_scene`.

    Attributes
    ----------
    rayscene : camplace.visibility.raycast.RayScene
    labels : (m,) int8
        LABEL_OCCLUDER (0) or LABEL_TARGET (1) per triangle (in ``rayscene.triangles`` order).
    albedo : (m,) float32
    normals : (m, 3) float64
        Unit face normals (right-hand rule on the float32 vertices).
    light_position_m : (3,) float64 or None
        None: no point light (ambient only).
    eps_m : float
        Offset of shadow-ray origins along the normal.
    """

    rayscene: Any
    labels: np.ndarray
    albedo: np.ndarray
    normals: np.ndarray
    light_position_m: np.ndarray | None
    eps_m: float

    @classmethod
    def build(
        cls,
        target: Sequence[tuple[np.ndarray, np.ndarray]] | tuple[np.ndarray, np.ndarray] | None,
        occluders: Sequence[tuple[np.ndarray, np.ndarray]] = (),
        light_position_m: Sequence[float] | None = None,
        settings: RenderSettings = RenderSettings(),
    ) -> "RenderScene":
        """Scene from world-space meshes.

        Parameters
        ----------
        target : (vertices (n, 3), faces (m, 3)) or a list of them, or None
            The target's triangles (labelled LABEL_TARGET).
        occluders : list of (vertices (n, 3), faces (m, 3))
        light_position_m : (3,) float or None
        settings : RenderSettings
            Albedos.
        """
        from camplace.visibility.raycast import RayScene

        if target is None:
            targets: list = []
        elif isinstance(target, tuple) and len(target) == 2 and np.asarray(target[1]).ndim == 2:
            targets = [target]
        else:
            targets = list(target)
        meshes, labels, albedo = [], [], []
        for (v, f), lab, alb in [(m, LABEL_OCCLUDER, settings.albedo_occluder) for m in occluders] + [
            (m, LABEL_TARGET, settings.albedo_target) for m in targets
        ]:
            f = np.asarray(f, dtype=np.int64).reshape(-1, 3)
            if len(f) == 0:
                continue
            meshes.append((np.asarray(v, dtype=np.float64), f))
            labels.append(np.full(len(f), lab, dtype=np.int8))
            albedo.append(np.full(len(f), alb, dtype=np.float32))
        rs = RayScene(meshes)
        tri = rs.triangles.astype(np.float64)
        if len(tri):
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            norm = np.linalg.norm(n, axis=1, keepdims=True)
            n = np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)
            flat = tri.reshape(-1, 3)
            diag = float(np.linalg.norm(flat.max(axis=0) - flat.min(axis=0)))
        else:
            n = np.zeros((0, 3))
            diag = 1.0
        light = None if light_position_m is None else np.asarray(light_position_m, dtype=np.float64).reshape(3)
        return cls(
            rayscene=rs,
            labels=np.concatenate(labels) if labels else np.zeros(0, np.int8),
            albedo=np.concatenate(albedo) if albedo else np.zeros(0, np.float32),
            normals=n,
            light_position_m=light,
            eps_m=max(1e-4 * diag, 1e-7),
        )


def scene_for_frame(instance, frame: int, *, with_target: bool = True, settings: RenderSettings = RenderSettings()) -> RenderScene:
    """The instance's scene in ``frame``: occluders (static and the frame's), the posed target unless
    ``with_target`` is False (the background image), and the instance's light."""
    occ = [(v, f) for _, v, f in instance.occluders_world(frame)]
    target = instance.target_world(frame) if with_target else None
    return RenderScene.build(target, occ, instance.light.position_m, settings)


def target_scene(vertices: np.ndarray, faces: np.ndarray) -> RenderScene:
    """A scene holding only a target mesh and no light (for predicted masks without an instance)."""
    return RenderScene.build((vertices, faces), (), None)


@dataclass(frozen=True, eq=False)
class RenderResult:
    """One rendered view.

    Attributes
    ----------
    image : (h, w) float32
        Linear radiance (glow included), not clipped.
    target_mask : (h, w) bool
        Pixels whose first hit is the target.
    depth : (h, w) float32
        Camera-frame z of the first hit, metres (inf where nothing is hit).
    label : (h, w) int8
        LABEL_NONE, LABEL_OCCLUDER or LABEL_TARGET per pixel.
    camera : CameraView
    """

    image: np.ndarray
    target_mask: np.ndarray
    depth: np.ndarray
    label: np.ndarray
    camera: CameraView

    @property
    def target_px(self) -> int:
        """Number of target pixels."""
        return int(self.target_mask.sum())

    def save(self, path: str | Path) -> None:
        """Write image, mask, depth and label to one ``.npz`` (atomically)."""
        import io

        buf = io.BytesIO()
        np.savez_compressed(buf, image=self.image, target_mask=self.target_mask, depth=self.depth, label=self.label)
        write_bytes_atomic(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | Path, camera: CameraView) -> "RenderResult":
        """Read what :meth:`save` wrote."""
        with np.load(Path(path)) as z:
            return cls(z["image"], z["target_mask"], z["depth"], z["label"], camera)


def _shade_rows(camera: CameraView, scene: RenderScene, settings: RenderSettings, rows: slice):
    origin, dirs = camera.rays(rows)
    h, w = dirs.shape[:2]
    d = dirs.reshape(-1, 3)
    o = np.broadcast_to(origin, d.shape)
    tri, t = scene.rayscene.first_hit(o, d)
    hit = tri >= 0
    img = np.full(len(d), settings.background, dtype=np.float32)
    label = np.full(len(d), LABEL_NONE, dtype=np.int8)
    depth = np.full(len(d), np.inf, dtype=np.float32)
    if np.any(hit):
        ti = tri[hit]
        th = t[hit]
        dh = d[hit]
        p = origin + dh * th[:, None]
        n = scene.normals[ti]
        # two-sided: turn the normal towards the camera
        flip = np.einsum("ij,ij->i", n, dh) > 0
        n[flip] *= -1.0
        shade = np.zeros(len(ti))
        if scene.light_position_m is not None:
            to_light = scene.light_position_m - p
            dist = np.linalg.norm(to_light, axis=1)
            cos = np.einsum("ij,ij->i", n, to_light) / np.maximum(dist, 1e-30)
            lit = cos > 0
            if settings.shadows and np.any(lit):
                origins = p[lit] + scene.eps_m * n[lit]
                blocked = scene.rayscene.occluded(origins, np.broadcast_to(scene.light_position_m, origins.shape))
                idx = np.nonzero(lit)[0]
                lit[idx[blocked]] = False
            shade = np.where(lit, settings.light_intensity * cos, 0.0)
        img[hit] = (scene.albedo[ti] * shade + settings.ambient).astype(np.float32)
        label[hit] = scene.labels[ti]
        depth[hit] = th.astype(np.float32)
    return rows, img.reshape(h, w), label.reshape(h, w), depth.reshape(h, w)


def _splat(image: np.ndarray, depth: np.ndarray, camera: CameraView, glow: GlowEmitters, min_sigma_px: float) -> None:
    """Add emitters' Gaussian glow to ``image`` in place (depth-tested against ``depth``)."""
    if len(glow) == 0:
        return
    uv, z = camera.project(glow.positions_m)
    h, w = image.shape
    fx = camera.K[0, 0]
    for i in np.nonzero((z > 0) & np.isfinite(uv[:, 0]))[0]:
        sigma = fx * glow.radius_m[i] / z[i]
        peak = glow.brightness[i]
        if sigma < min_sigma_px:
            peak = peak * (sigma / min_sigma_px) ** 2  # same flux, wider splat
            sigma = min_sigma_px
        r = int(np.ceil(3.5 * sigma))
        u0, v0 = uv[i]
        x0, x1 = max(int(np.floor(u0)) - r, 0), min(int(np.ceil(u0)) + r + 1, w)
        y0, y1 = max(int(np.floor(v0)) - r, 0), min(int(np.ceil(v0)) + r + 1, h)
        if x0 >= x1 or y0 >= y1 or peak == 0:
            continue
        xs = np.arange(x0, x1) - u0
        ys = np.arange(y0, y1) - v0
        g = peak * np.exp(-0.5 * (ys[:, None] ** 2 + xs[None, :] ** 2) / sigma**2)
        visible = depth[y0:y1, x0:x1] > z[i]
        image[y0:y1, x0:x1] += np.where(visible, g, 0.0).astype(np.float32)


def add_glow(result: RenderResult, emitters: Any, settings: RenderSettings = RenderSettings()) -> None:
    """Add emitters' glow to an existing render's image in place (depth-tested against its depth)."""
    glow = as_glow(emitters, settings)
    if glow is not None:
        _splat(result.image, result.depth, result.camera, glow, settings.min_sigma_px)


def render_view(
    camera: CameraView,
    scene: RenderScene,
    *,
    settings: RenderSettings = RenderSettings(),
    emitters: Any = None,
    workers: int | None = None,
    block_rows: int = 64,
) -> RenderResult:
    """Ray-cast one image.

    Parameters
    ----------
    camera : CameraView
        Pose, intrinsics, size (and distortion) of the view.
    scene : RenderScene
    settings : RenderSettings
        Albedo of triangles comes from the scene; the other shading constants from here.
    emitters : GlowEmitters, instance Emitters, list of (position, brightness), or None
        Volumetric emitters added as glow (see the module docstring).
    workers : int or None
        Threads casting row blocks (default: the number of CPUs, at most 8). Embree releases the GIL.
    block_rows : int
        Image rows per work item.

    Returns
    -------
    RenderResult
    """
    h, w = camera.height, camera.width
    image = np.empty((h, w), dtype=np.float32)
    label = np.empty((h, w), dtype=np.int8)
    depth = np.empty((h, w), dtype=np.float32)
    blocks = [slice(s, min(s + block_rows, h)) for s in range(0, h, block_rows)]
    workers = thread_count(workers)

    def store(res) -> None:
        rows, im, lab, dep = res
        image[rows], label[rows], depth[rows] = im, lab, dep

    if workers == 1 or len(blocks) == 1:
        for b in blocks:
            store(_shade_rows(camera, scene, settings, b))
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            for res in pool.map(lambda b: _shade_rows(camera, scene, settings, b), blocks):
                store(res)
    glow = as_glow(emitters, settings)
    if glow is not None:
        _splat(image, depth, camera, glow, settings.min_sigma_px)
    return RenderResult(image=image, target_mask=label == LABEL_TARGET, depth=depth, label=label, camera=camera)


# --------------------------------------------------------------------------------------------------
# image files


def quantise(image: np.ndarray, bit_depth: int = 8) -> np.ndarray:
    """Linear [0, 1] float image to uint8 / uint16 (clipped, rounded)."""
    if bit_depth not in (8, 16):
        raise CamplaceError(f"bit depth must be 8 or 16, got {bit_depth}")
    top = 255 if bit_depth == 8 else 65535
    q = np.rint(np.clip(np.asarray(image, dtype=np.float64), 0.0, 1.0) * top)
    return q.astype(np.uint8 if bit_depth == 8 else np.uint16)


def encode_png(array: np.ndarray) -> bytes:
    """PNG bytes of a uint8/uint16 array (gray or BGR)."""
    import cv2

    ok, buf = cv2.imencode(".png", array)
    if not ok:  # pragma: no cover - OpenCV failure
        raise CamplaceError("OpenCV could not encode a PNG")
    return buf.tobytes()


def write_png(path: str | Path, image: np.ndarray, bit_depth: int = 8) -> None:
    """Write a float image (linear, clipped to [0, 1]) or an integer array as PNG, atomically."""
    arr = np.asarray(image)
    if arr.dtype not in (np.uint8, np.uint16):
        arr = quantise(arr, bit_depth)
    write_bytes_atomic(path, encode_png(arr))


def write_mask_png(path: str | Path, mask: np.ndarray) -> None:
    """Write a boolean mask as an 8-bit PNG (0 / 255), atomically."""
    write_bytes_atomic(path, encode_png(np.where(np.asarray(mask, dtype=bool), 255, 0).astype(np.uint8)))


def read_image(path: str | Path) -> np.ndarray:
    """Read an image (any depth, gray or colour) as float32 in [0, 1] (colour stays BGR, alpha dropped)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise CamplaceError(f"{path}: cannot read image (missing file or a format OpenCV does not know)")
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    if img.dtype == np.uint8:
        return img.astype(np.float32) / 255.0
    if img.dtype == np.uint16:
        return img.astype(np.float32) / 65535.0
    return img.astype(np.float32)
