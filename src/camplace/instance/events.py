"""Procedural dynamic events for the built-in instances (the thesis's Experiments 01 and 02).

Each function returns instance-file data (a TOML dict, metres) with inline per-frame emitters, so
a built-in is parsed exactly like a file and ``camplace init`` can write it out. Both take a
``seed`` and draw everything random from one ``numpy.random.default_rng(seed)``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

N_FRAMES = 36

# cameras shared by the two outdoor experiments: 1/1.8" sensor, 8 mm lens (48 x 36 deg field of view)
_CAMERA = {
    "sensor_width_mm": 7.18,
    "sensor_height_mm": 5.32,
    "focal_length_mm": 8.0,
    "width_px": 1280,
    "height_px": 960,
}


def _round(a: np.ndarray, digits: int = 4) -> list:
    """Plain nested lists of rounded floats (small, exact-to-print TOML arrays)."""
    return np.round(np.asarray(a, dtype=np.float64), digits).tolist()


def flyby_trajectory(t: np.ndarray) -> np.ndarray:
    """Nucleus centre on the flyby's hyperbolic trajectory, ``t`` in [0, 1] (closest approach at 0.5).

    x = 30 sinh(u), y = 6 (cosh(u) - 1) - 10, z = 2 u with u = 3.2 (t - 0.5): it enters at x = -74 m,
    passes 10 m below the camera box's y = 0 at x = 0, and leaves at x = +74 m.

    Returns
    -------
    (len(t), 3) float64
    """
    u = 3.2 * (np.asarray(t, dtype=np.float64) - 0.5)
    return np.column_stack([30.0 * np.sinh(u), 6.0 * (np.cosh(u) - 1.0) - 10.0, 2.0 * u])


def comet_flyby_toml(seed: int = 0) -> dict[str, Any]:
    """Experiment 01: a comet nucleus with a coma and a tail crossing the field on a hyperbola.

    A 2 m bilobed nucleus moves over 36 frames along :func:`flyby_trajectory`; its coma is a
    Gaussian particle cloud (sigma 2.5 m) and its tail a fan of particles pointing away from the
    sun (the light, far away), 25 m long, spreading and fading with distance. The likelihood of a
    frame peaks at closest approach (Gaussian in time, sigma 8 frames). Cameras stand in a
    120 x 30 x 24 m box beside the trajectory (y from 5 to 35 m) and aim at 3 key frames.
    """
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, N_FRAMES)
    centres = flyby_trajectory(t)
    sun = np.array([-3000.0, -4000.0, 1500.0])
    likelihood = np.exp(-0.5 * ((np.arange(N_FRAMES) - (N_FRAMES - 1) / 2) / 8.0) ** 2)
    frames = []
    n_coma, n_tail = 120, 120
    for f in range(N_FRAMES):
        c = centres[f]
        anti_sun = (c - sun) / np.linalg.norm(c - sun)
        coma = c + rng.normal(0.0, 2.5, size=(n_coma, 3))
        coma_w = np.exp(-0.5 * (np.linalg.norm(coma - c, axis=1) / 2.5) ** 2)
        s = rng.uniform(0.0, 1.0, n_tail) ** 0.7  # more particles near the head
        spread = 0.5 + 3.0 * s
        tail = c + np.outer(25.0 * s, anti_sun) + rng.normal(0.0, 1.0, size=(n_tail, 3)) * spread[:, None]
        tail_w = 0.6 * (1.0 - s) + 0.05
        pos = np.concatenate([coma, tail])
        w = np.concatenate([coma_w, tail_w])
        w = w / w.sum()  # the coma + tail together weigh as much as the nucleus
        frames.append(
            {
                "weight": float(np.round(likelihood[f], 6)),
                "time_s": float(f),
                "position_m": _round(c),
                "rotation_deg": [0.0, 0.0, float(np.round(10.0 * f, 3))],  # the nucleus tumbles
                "target_weight": 1.0,
                "emitters": {"positions_m": _round(pos), "weights": _round(w, 6)},
            }
        )
    return {
        "schema_version": 1,
        "name": "comet-flyby",
        "k": 3,
        "run": {"candidates": 1000, "points": 10800, "sampler": "chaotic", "seed": int(seed), "time_limit_s": 60.0,
                "orientations": 3},
        "camera": {**_CAMERA, "near_m": 1.0, "far_m": 250.0},
        "volume": {"min_m": [-60.0, 5.0, -12.0], "max_m": [60.0, 35.0, 12.0]},
        "light": {"position_m": sun.tolist()},
        "quality": {"mode": "binary", "max_incidence_deg": 85.0, "require_light": True},
        "target": {"name": "nucleus", "shape": "bilobed-comet", "length_m": 2.0, "seed": 11, "subdivisions": 4},
        "frames": frames,
    }


VOLCANO = {"size_m": [400.0, 400.0], "height_m": 80.0, "base_radius_m": 150.0, "crater_radius_m": 25.0,
           "crater_depth_m": 20.0, "cells": 100}


def plume_intensity(n_frames: int, peak: int, width: float = 5.0) -> np.ndarray:
    """Relative plume intensity per step: a Gaussian pulse peaking at step ``peak``."""
    s = np.arange(n_frames, dtype=np.float64)
    return np.exp(-0.5 * ((s - peak) / width) ** 2)


def volcanic_eruption_toml(seed: int = 0) -> dict[str, Any]:
    """Experiment 02: a plume rising from a crater, spreading and drifting with the wind.

    Terrain: the procedural ``volcano`` heightfield (400 x 400 m, an 80 m cone with a 25 m crater),
    an occluder marked ``ground`` so that no camera stands in or under it. Over 36 steps a plume
    rises from the crater at 6 m per step, its radius growing from 8 m and its axis drifting
    downwind (+x, 2.5 m per step); its intensity is a Gaussian pulse (sigma 5 steps) peaking at a
    step drawn from ``seed`` (8..27), which is also each frame's likelihood. The target is the vent
    (a 6 m glowing sphere in the crater, small weight); emitters carry the plume.
    """
    rng = np.random.default_rng(seed)
    peak = int(rng.integers(8, 28))
    intensity = plume_intensity(N_FRAMES, peak)
    rim = VOLCANO["height_m"] * (1.0 - VOLCANO["crater_radius_m"] / VOLCANO["base_radius_m"])
    vent = np.array([0.0, 0.0, rim - VOLCANO["crater_depth_m"] + 6.0])
    frames = []
    n_particles = 200
    for f in range(N_FRAMES):
        top = 10.0 + 6.0 * f  # plume column height above the vent
        h = rng.uniform(0.0, 1.0, n_particles) ** 0.8 * top
        radius = 8.0 + 0.35 * h
        drift = 2.5 * f * (h / max(top, 1e-9))
        ang = rng.uniform(0.0, 2.0 * np.pi, n_particles)
        rr = radius * np.sqrt(rng.uniform(0.0, 1.0, n_particles))
        pos = np.column_stack([vent[0] + drift + rr * np.cos(ang), vent[1] + rr * np.sin(ang), vent[2] + h])
        w = np.exp(-h / (0.7 * top + 10.0))
        w = intensity[f] * w / w.sum()
        frames.append(
            {
                "weight": float(np.round(intensity[f], 6)),
                "time_s": float(10.0 * f),
                "position_m": _round(vent),
                "target_weight": float(np.round(0.1 * intensity[f] + 0.01, 6)),
                "emitters": {"positions_m": _round(pos), "weights": _round(w, 8)},
            }
        )
    return {
        "schema_version": 1,
        "name": "volcanic-eruption",
        "k": 3,
        "run": {"candidates": 2000, "points": 3600, "sampler": "chaotic", "seed": int(seed), "time_limit_s": 60.0,
                "orientations": 1},
        "camera": {**_CAMERA, "near_m": 2.0, "far_m": 1500.0},
        "volume": {"min_m": [-195.0, -195.0, 0.5], "max_m": [195.0, 195.0, 150.0]},
        "light": {"position_m": [2000.0, -3000.0, 4000.0]},
        "quality": {"mode": "binary", "require_light": False},
        "target": {"name": "vent", "shape": "sphere", "radius_m": 6.0, "subdivisions": 3},
        "occluders": [{"name": "volcano", "shape": "volcano", **VOLCANO, "ground": True}],
        "frames": frames,
    }
