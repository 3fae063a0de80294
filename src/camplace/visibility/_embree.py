"""Embree's C API through ctypes, for packets of occlusion rays cast from compiled code.

embreex (the Python binding camplace builds on) casts one ray at a time (``rtcOccluded1`` in a
Cython loop). The segments of one chunk of cameras are coherent (one camera, neighbouring points),
which Embree traces faster in packets of 4, 8 or 16 rays (``rtcOccluded4/8/16``, SIMD across the
packet). This module opens the Embree library that embreex ships (the same build, so the same
triangle test), makes a device and triangle scenes, and hands the compiled kernel
:func:`camplace.visibility._kernels.occluded_packets` the addresses it calls.

Nothing here is needed for a correct answer: :func:`packet_api` returns None where the library
cannot be found or does not answer as expected, and :class:`camplace.visibility.raycast.RayScene`
then casts through embreex as before. Set ``CAMPLACE_EMBREE_PACKETS=0`` to force that.
"""

from __future__ import annotations

import ctypes
import functools
import glob
import logging
import os
import threading
import weakref
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["PacketAPI", "packet_api", "PacketScene"]

# enum values of embree4/rtcore_*.h
_GEOMETRY_TYPE_TRIANGLE = 0
_BUFFER_TYPE_INDEX, _BUFFER_TYPE_VERTEX = 0, 1
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003
_PROPERTY_VERSION = 0
_PROPERTY_NATIVE_RAY = {4: 32, 8: 33, 16: 34}
_VP = ctypes.c_void_p


@dataclass(frozen=True)
class PacketAPI:
    """An open Embree library and one device (process-wide).

    Attributes
    ----------
    lib : ctypes.CDLL
    device : int
        The ``RTCDevice`` handle.
    width : int
        Rays per call: 16, 8 or 4 (the widest packet the CPU runs natively), or 1.
    occluded : int
        Address of ``rtcOccluded16/8/4`` (``(valid*, scene, ray*, args*)``) or, at width 1,
        ``rtcOccluded1`` (``(scene, ray*, args*)``).
    version : int
        Embree's version (e.g. 40400 for 4.4.0).
    """

    lib: ctypes.CDLL
    device: int
    width: int
    occluded: int
    version: int

    def error(self) -> int:
        """Embree's last error code on the device (0: none), cleared by reading it."""
        return int(self.lib.rtcGetDeviceError(self.device))


def _library_path() -> str | None:
    """The Embree 4 shared library embreex loads (``embreex.libs/libembree4*`` beside the package,
    or embreex's own folder), None when there is none."""
    try:
        import embreex
    except ImportError:
        return None
    here = os.path.dirname(os.path.abspath(embreex.__file__))
    for folder in (os.path.join(os.path.dirname(here), "embreex.libs"), here, os.path.join(here, ".dylibs")):
        found = sorted(glob.glob(os.path.join(folder, "libembree4*")) + glob.glob(os.path.join(folder, "embree4*.dll")))
        if found:
            return found[0]
    return None


def _declare(lib: ctypes.CDLL) -> None:
    """Argument and result types of the functions used here."""
    lib.rtcNewDevice.restype, lib.rtcNewDevice.argtypes = _VP, [ctypes.c_char_p]
    lib.rtcGetDeviceProperty.restype, lib.rtcGetDeviceProperty.argtypes = ctypes.c_ssize_t, [_VP, ctypes.c_int]
    lib.rtcGetDeviceError.restype, lib.rtcGetDeviceError.argtypes = ctypes.c_int, [_VP]
    lib.rtcNewScene.restype, lib.rtcNewScene.argtypes = _VP, [_VP]
    lib.rtcReleaseScene.restype, lib.rtcReleaseScene.argtypes = None, [_VP]
    lib.rtcNewGeometry.restype, lib.rtcNewGeometry.argtypes = _VP, [_VP, ctypes.c_int]
    lib.rtcSetNewGeometryBuffer.restype = _VP
    lib.rtcSetNewGeometryBuffer.argtypes = [_VP, ctypes.c_int, ctypes.c_uint, ctypes.c_int, ctypes.c_size_t, ctypes.c_size_t]
    for name in ("rtcCommitGeometry", "rtcReleaseGeometry", "rtcCommitScene"):
        getattr(lib, name).restype, getattr(lib, name).argtypes = None, [_VP]
    lib.rtcAttachGeometry.restype, lib.rtcAttachGeometry.argtypes = ctypes.c_uint, [_VP, _VP]


def packet_api() -> PacketAPI | None:
    """The process's Embree device for packet casts, or None (embreex casts one ray at a time).

    None when ``CAMPLACE_EMBREE_PACKETS=0``, when no Embree 4 library is found beside embreex, or
    when it does not load, make a device or report a version 4. One device per process: a child
    made by ``fork`` makes its own (the parent's build threads are not there).
    """
    return _packet_api(os.getpid())


@functools.cache
def _packet_api(pid: int) -> PacketAPI | None:
    """:func:`packet_api` of process ``pid``."""
    if os.environ.get("CAMPLACE_EMBREE_PACKETS", "1").strip() in ("0", "false", "no"):
        return None
    path = _library_path()
    if path is None:
        return None
    try:
        lib = ctypes.CDLL(path)
        _declare(lib)
        device = lib.rtcNewDevice(None)
        if not device:
            return None
        version = int(lib.rtcGetDeviceProperty(device, _PROPERTY_VERSION))
        if version // 10000 != 4:
            return None
        width = next((w for w in (16, 8, 4) if lib.rtcGetDeviceProperty(device, _PROPERTY_NATIVE_RAY[w]) == 1), 1)
        fn = lib.rtcOccluded1 if width == 1 else getattr(lib, f"rtcOccluded{width}")
        api = PacketAPI(lib, int(device), width, int(ctypes.cast(fn, _VP).value), version)
    except (OSError, AttributeError) as exc:  # another build of Embree: embreex casts
        log.debug("embree packets unavailable (%s): casting one ray at a time", exc)
        return None
    if not answers_as_expected(api):
        log.warning("Embree %d's packet casts did not answer a test as expected: casting one ray at a time "
                    "through embreex", api.version)
        return None
    return api


def answers_as_expected(api: PacketAPI) -> bool:
    """Whether packet casts through ``api`` give the known answers on one triangle: the square of
    side 2 in the plane x = 0 (two triangles) and ``2 width + 3`` segments along +x from x = -1,
    blocked exactly when they reach x = 0 inside the square (a partial last packet included), with
    no error on the device. Guards against a library whose structures differ from the ones
    declared here: the cast then falls back to embreex rather than answering wrongly."""
    from camplace.visibility._castkernels import occluded_packets

    tri = np.array([[[0, -1, -1], [0, 1, -1], [0, 1, 1]], [[0, -1, -1], [0, 1, 1], [0, -1, 1]]], dtype=np.float32)
    n = 2 * api.width + 3
    i = np.arange(n)
    inside = i % 3 != 1  # y within the square or 3 m off it
    long = i % 4 != 3  # the segment reaches x = +1, or stops at x = -0.5
    origins = np.column_stack([np.full(n, -1.0), np.where(inside, 0.5 - 0.1 * (i % 5), 3.0), 0.2 - 0.05 * (i % 7)])
    directions = np.column_stack([np.where(long, 2.0, 0.5), np.zeros(n), np.zeros(n)])
    got = np.zeros(n, dtype=bool)
    try:
        scene = PacketScene(api, tri)
        occluded_packets(np.uint64(api.occluded), np.uint64(scene.handle), api.width,
                         origins.astype(np.float32), directions.astype(np.float32), got)
    except RuntimeError:
        return False
    return bool(np.array_equal(got, inside & long) and api.error() == 0)


_BUILD_LOCK = threading.Lock()


class PacketScene:
    """A committed Embree scene of one float32 triangle soup, released when garbage collected.

    Parameters
    ----------
    api : PacketAPI
    triangles : (t, 3, 3) float32
        Vertices of each triangle (world metres), t >= 1.

    Raises
    ------
    RuntimeError
        When Embree reports an error while building (the caller then uses embreex).
    """

    def __init__(self, api: PacketAPI, triangles: np.ndarray) -> None:
        tri = np.ascontiguousarray(triangles, dtype=np.float32).reshape(-1, 3, 3)
        n = len(tri)
        lib = api.lib
        with _BUILD_LOCK:  # one build at a time: Embree builds on its own threads
            api.error()
            scene = lib.rtcNewScene(api.device)
            geom = lib.rtcNewGeometry(api.device, _GEOMETRY_TYPE_TRIANGLE)
            # Embree's own buffers (it pads the vertex buffer for its 16-byte loads)
            vb = lib.rtcSetNewGeometryBuffer(geom, _BUFFER_TYPE_VERTEX, 0, _FORMAT_FLOAT3, 12, 3 * n)
            ib = lib.rtcSetNewGeometryBuffer(geom, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT3, 12, n)
            if not (scene and geom and vb and ib):
                raise RuntimeError(f"embree error {api.error()} while making a scene")
            ctypes.memmove(vb, tri.ctypes.data, tri.nbytes)
            index = np.arange(3 * n, dtype=np.uint32)  # (held: a temporary's memory may be gone)
            ctypes.memmove(ib, index.ctypes.data, index.nbytes)
            lib.rtcCommitGeometry(geom)
            lib.rtcAttachGeometry(scene, geom)
            lib.rtcReleaseGeometry(geom)
            lib.rtcCommitScene(scene)
            code = api.error()
        self.api = api
        self.handle = int(scene)
        self.release = weakref.finalize(self, lib.rtcReleaseScene, self.handle)  # (when collected)
        if code:
            raise RuntimeError(f"embree error {code} while building a scene of {n} triangles")
