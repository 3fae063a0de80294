"""Packet casts through Embree's C API (camplace.visibility._embree, _castkernels) against embreex's
one-ray-at-a-time casts (the oracle: the path camplace used before, and the fallback)."""

from __future__ import annotations

import ctypes
import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from camplace.visibility import _embree
from camplace.visibility._castkernels import occluded_packets
from camplace.visibility.raycast import RayScene

API = _embree.packet_api()
pytestmark = pytest.mark.skipif(API is None, reason="no Embree 4 library beside embreex")


def _widths() -> list[tuple[int, int]]:
    """(width, address) of every packet call this CPU runs natively, and the single-ray call."""
    out = [(1, ctypes.cast(API.lib.rtcOccluded1, ctypes.c_void_p).value)]
    for w, prop in _embree._PROPERTY_NATIVE_RAY.items():
        if API.lib.rtcGetDeviceProperty(API.device, prop) == 1:
            out.append((w, ctypes.cast(getattr(API.lib, f"rtcOccluded{w}"), ctypes.c_void_p).value))
    return out


def _scene_and_segments(seed: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two spheres' triangles and ``n`` segments from a shell around them to points near them,
    about a third blocked; some of zero length, some ending 1e-4 m off the surface (as the
    visibility engine's do: Embree does not promise either answer for a hit exactly at the end)."""
    rng = np.random.default_rng(seed)
    a = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    b = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    b.apply_translation([1.8, 0.3, 0.0])
    tri = np.concatenate([a.triangles, b.triangles]).astype(np.float32)
    origins = rng.normal(size=(n, 3))
    origins *= (4.0 + rng.random(n))[:, None] / np.linalg.norm(origins, axis=1)[:, None]
    ends = rng.normal(size=(n, 3)) * 1.3
    ends[: n // 10] = a.vertices[rng.integers(0, len(a.vertices), n // 10)] * (1.0 + 1e-4)  # by the surface
    ends[n // 10: n // 10 + 7] = origins[n // 10: n // 10 + 7]  # zero length
    o = origins.astype(np.float32)
    return tri, o, (ends.astype(np.float32) - o)


def _embreex(tri: np.ndarray, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    scene = RayScene.from_triangles(tri)
    return scene._scene.run(o, d, dists=np.ones(len(o), np.float32), query="OCCLUDED") != -1


@pytest.mark.parametrize("n", [0, 1, 15, 16, 17, 5003])
def test_every_width_equals_embreex(n: int) -> None:
    tri, o, d = _scene_and_segments(n, max(n, 1))
    o, d = o[:n], d[:n]
    want = _embreex(tri, o, d)
    scene = _embree.PacketScene(API, tri)
    for width, fn in _widths():
        got = np.ones(n, dtype=bool) if n % 2 else np.zeros(n, dtype=bool)  # every entry must be written
        occluded_packets(np.uint64(fn), np.uint64(scene.handle), width, o, d, got)
        assert np.array_equal(got, want), width
    if n > 1000:
        assert 0.1 < want.mean() < 0.9  # both answers occur


def test_rayscene_uses_packets_and_writes_in_place() -> None:
    tri, o, d = _scene_and_segments(7, 2000)
    scene = RayScene.from_triangles(tri)
    out = np.zeros(4000, dtype=bool)[::2]  # not contiguous: written through a copy
    got = scene.occluded_dir(o, d, out=out)
    assert got is out and scene._packets is not None
    assert np.array_equal(out, _embreex(tri, o, d))


def test_scene_is_released_when_collected() -> None:
    import gc

    tri, _, _ = _scene_and_segments(3, 10)
    scene = _embree.PacketScene(API, tri)
    release = scene.release
    assert release.alive
    del scene
    gc.collect()
    assert not release.alive  # rtcReleaseScene ran


def test_switched_off_casts_through_embreex() -> None:
    code = (
        "import numpy as np\n"
        "from camplace.visibility.raycast import RayScene\n"
        "t = np.array([[[0, -1, -1], [0, 1, -1], [0, 0, 1]]], np.float32)\n"
        "s = RayScene.from_triangles(t)\n"
        "o = np.array([[-1, 0, 0], [-1, 5, 0]], np.float32); d = np.array([[2, 0, 0], [2, 0, 0]], np.float32)\n"
        "print(s.occluded_dir(o, d).tolist(), s._packets)\n"
    )
    env_off = {"CAMPLACE_EMBREE_PACKETS": "0"}
    import os

    for env, packets in ((env_off, "None"), ({}, "<camplace")):
        out = subprocess.run([sys.executable, "-c", code], env={**os.environ, **env}, capture_output=True, text=True,
                             check=True).stdout
        assert out.startswith("[True, False]"), out
        assert packets in out, out


def _cast_in_child(queue) -> None:
    tri, o, d = _scene_and_segments(5, 3000)
    assert _embree.packet_api() is not _embree._packet_api(os.getppid())  # not the parent's device
    queue.put((0, RayScene.from_triangles(tri).occluded_dir(o, d)))


def test_a_forked_child_makes_its_own_device_and_casts_the_same() -> None:
    import multiprocessing as mp

    tri, o, d = _scene_and_segments(5, 3000)
    want = RayScene.from_triangles(tri).occluded_dir(o, d)  # the parent's device exists now
    ctx = mp.get_context("fork")
    queue = ctx.Queue()
    child = ctx.Process(target=_cast_in_child, args=(queue,))
    child.start()
    _, got = queue.get(timeout=60)
    child.join(timeout=60)
    assert child.exitcode == 0
    assert np.array_equal(got, want)


def test_a_library_that_answers_wrongly_is_not_used() -> None:
    """The start-up test (answers_as_expected) passes on this library and fails when the call does
    not match the packet's layout (rtcOccluded4 given packets of 16, or 16 given packets of 4)."""
    from dataclasses import replace

    assert _embree.answers_as_expected(API)
    widths = dict(_widths())
    if 4 in widths and 16 in widths:
        assert not _embree.answers_as_expected(replace(API, width=16, occluded=widths[4]))
        assert not _embree.answers_as_expected(replace(API, width=4, occluded=widths[16]))
