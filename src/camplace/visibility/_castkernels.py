"""The compiled (numba, GIL-free) loop that casts segments through Embree in packets.

:func:`occluded_packets` fills one packet of rays at a time (structure of arrays, aligned as
Embree requires) from the chunk's float32 segments and calls ``rtcOccluded16/8/4`` (or
``rtcOccluded1``) by address (:mod:`camplace.visibility._embree`). The addresses arrive as plain
integers and are called through :func:`_call3` / :func:`_call4` (a cast to a function pointer in
the generated code), so the kernel has an ordinary signature that numba caches and that the
install step precompiles.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

_JIT = {"nogil": True, "cache": True, "error_model": "numpy", "boundscheck": False}

MAX_WIDTH = 16
_FIELDS = 12  # org_x, org_y, org_z, tnear, dir_x, dir_y, dir_z, time, tfar, mask, id, flags
_ALIGN_FLOATS = 16  # 64 bytes: RTCRay16's alignment, enough for every width


def _void_sig(*args):
    """``void(args...)`` when every argument is a 64-bit integer (an address), else None (no match)."""
    args = tuple(types.unliteral(a) for a in args)
    if all(isinstance(a, types.Integer) and a.bitwidth == 64 for a in args):
        return types.void(*args)
    return None


@intrinsic
def _call3(typingctx, fn, a, b, c):  # pragma: no cover - compiled
    """Call the C function at address ``fn`` with three 64-bit arguments (pointers), no result."""
    sig = _void_sig(fn, a, b, c)

    def codegen(context, builder, signature, args):
        i64 = ir.IntType(64)
        fnty = ir.FunctionType(ir.VoidType(), [i64, i64, i64])
        builder.call(builder.inttoptr(args[0], fnty.as_pointer()), args[1:])
        return context.get_dummy_value()

    return sig, codegen


@intrinsic
def _call4(typingctx, fn, a, b, c, d):  # pragma: no cover - compiled
    """Call the C function at address ``fn`` with four 64-bit arguments (pointers), no result."""
    sig = _void_sig(fn, a, b, c, d)

    def codegen(context, builder, signature, args):
        i64 = ir.IntType(64)
        fnty = ir.FunctionType(ir.VoidType(), [i64, i64, i64, i64])
        builder.call(builder.inttoptr(args[0], fnty.as_pointer()), args[1:])
        return context.get_dummy_value()

    return sig, codegen


@numba.njit(**_JIT)
def occluded_packets(fn, scene, width, origins, directions, out):  # pragma: no cover - compiled
    """Whether each segment ``origins[i] + t directions[i]``, t in [0, 1], meets a triangle.

    Parameters
    ----------
    fn : uint64
        Address of ``rtcOccluded{width}`` (``rtcOccluded1`` at width 1).
    scene : uint64
        A committed ``RTCScene``.
    width : int
        Rays per call: 1, 4, 8 or 16.
    origins, directions : (n, 3) float32
        Segment starts and end-minus-start (world metres).
    out : (n,) bool
        Written: True where the segment is blocked (Embree sets ``tfar`` to -inf on a hit).
    """
    w = width
    buf = np.empty(_FIELDS * MAX_WIDTH + _ALIGN_FLOATS, dtype=np.float32)
    start = ((-buf.ctypes.data) % (4 * _ALIGN_FLOATS)) // 4
    ray = buf[start:start + _FIELDS * w]
    bits = ray.view(np.uint32)
    vbuf = np.empty(MAX_WIDTH + _ALIGN_FLOATS, dtype=np.int32)
    vstart = ((-vbuf.ctypes.data) % (4 * _ALIGN_FLOATS)) // 4
    valid = vbuf[vstart:vstart + w]
    for t in range(w):  # fields that no ray changes
        ray[3 * w + t] = 0.0  # tnear
        ray[7 * w + t] = 0.0  # time
        bits[9 * w + t] = 0xFFFFFFFF  # mask
        bits[10 * w + t] = 0  # id
        bits[11 * w + t] = 0  # flags
    n = origins.shape[0]
    ray_at, valid_at = ray.ctypes.data, valid.ctypes.data
    for s in range(0, n, w):
        m = min(w, n - s)
        for t in range(w):
            if t < m:
                i = s + t
                ray[t] = origins[i, 0]
                ray[w + t] = origins[i, 1]
                ray[2 * w + t] = origins[i, 2]
                ray[4 * w + t] = directions[i, 0]
                ray[5 * w + t] = directions[i, 1]
                ray[6 * w + t] = directions[i, 2]
                ray[8 * w + t] = 1.0
                valid[t] = -1
            else:
                valid[t] = 0
        if w == 1:
            _call3(fn, scene, ray_at, 0)
        else:
            _call4(fn, valid_at, scene, ray_at, 0)
        for t in range(m):
            out[s + t] = ray[8 * w + t] < 0.0
