"""Render-time benchmark: one 640 x 480 view of the built-in comet-67p-bunker scene (target: <= 1 s on 2 cores).

Run from the repository root::

    PYTHONPATH=src python benchmarks/render.py [--repeat 5] [--width 640 --height 480] [--emitters 1000]

Prints the scene build time, then the median and best wall time of a full render (primary rays,
Lambertian shading, shadow rays) with 1 thread and with all cores, and the glow-splat time of
``--emitters`` random emitters.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--emitters", type=int, default=1000)
    args = ap.parse_args()

    from camplace.instance import builtin
    from camplace.sampling import look_at
    from camplace.validation.cameras import CameraView
    from camplace.validation.render import GlowEmitters, RenderSettings, render_view, scene_for_frame

    inst = builtin("comet-67p-bunker")
    t0 = time.perf_counter()
    scene = scene_for_frame(inst, 0)
    build_s = time.perf_counter() - t0
    aim = inst.target_centre(0)
    pos = np.array([10.0, 0.8, 2.2])
    R = look_at(pos[None], aim[None])[0]
    cm = inst.camera
    fx = cm.focal_length_mm * args.width / cm.sensor_width_mm
    fy = cm.focal_length_mm * args.height / cm.sensor_height_mm
    K = np.array([[fx, 0, (args.width - 1) / 2], [0, fy, (args.height - 1) / 2], [0, 0, 1]])
    cam = CameraView("bench", pos, R, K, args.width, args.height)
    cores = os.cpu_count() or 1
    print(f"scene: {len(scene.rayscene):,} triangles, built in {build_s:.3f} s; image {args.width} x {args.height}; {cores} CPU(s)")
    render_view(cam, scene)  # warm-up (thread pool, Embree BVH)
    for workers in sorted({1, min(cores, 8)}):
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            res = render_view(cam, scene, workers=workers)
            times.append(time.perf_counter() - t0)
        rays = args.width * args.height + int(res.depth[np.isfinite(res.depth)].size)
        print(
            f"render, {workers} thread(s): median {statistics.median(times):.3f} s, best {min(times):.3f} s "
            f"(~{rays / statistics.median(times) / 1e6:.1f} M rays/s incl. shadow rays; {res.target_px} target px)"
        )
    rng = np.random.default_rng(0)
    glow = GlowEmitters(aim + rng.normal(0, 0.3, (args.emitters, 3)), rng.uniform(0.05, 0.3, args.emitters), 0.01)
    t0 = time.perf_counter()
    render_view(cam, scene, emitters=glow, settings=RenderSettings())
    with_glow = time.perf_counter() - t0
    print(f"render with {args.emitters} glow emitters: {with_glow:.3f} s")


if __name__ == "__main__":
    main()
