"""The report's figures, drawn with matplotlib (the optional ``report`` extra) and returned as PNG bytes.

Figures are made with :class:`matplotlib.figure.Figure` and the Agg canvas directly (no pyplot
global state), so they can be drawn from any thread.
"""

from __future__ import annotations

import io
from typing import Sequence

import numpy as np

from camplace.errors import CamplaceError

__all__ = [
    "MissingExtraError",
    "require_matplotlib",
    "histogram_png",
    "sampler_png",
    "cones_png",
    "legacy_scatter_png",
    "light_curves_png",
    "robust_png",
]

SAMPLER_COLOURS = {"chaotic": "#d62728", "sobol": "#2ca02c", "uniform": "#1f77b4"}
OPT_COLOUR = "#d62728"
DPI = 100


class MissingExtraError(CamplaceError, ImportError):
    """An optional dependency is missing (a CamplaceError, so the CLI prints one line and exits 2)."""


def require_matplotlib():
    """Import matplotlib's Figure and Agg canvas, or say how to install the ``report`` extra."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise MissingExtraError("the report needs the optional report extra: pip install 'camplace[report]'") from None
    return Figure, FigureCanvasAgg


def _figure(width_in: float, height_in: float):
    Figure, Canvas = require_matplotlib()
    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")
    Canvas(fig)
    return fig


def plain(text: str) -> str:
    """A user string shown as is by matplotlib (no mathtext: ``$`` is escaped)."""
    return str(text).replace("$", r"\$")


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def histogram_png(values: np.ndarray, optimised: float, title: str, *, run_objective: float | None = None,
                  xlabel: str = "objective (observed weight)") -> bytes:
    """Histogram of campaign objectives with the optimised system (and the run's, when different) marked.

    Parameters
    ----------
    values : (n,) float64
    optimised : float
    title : str
    run_objective : float or None
        Drawn too when it differs from ``optimised``.
    """
    v = np.asarray(values, dtype=np.float64)
    fig = _figure(6.4, 3.4)
    ax = fig.add_subplot()
    lo = min(float(v.min()), optimised)
    hi = max(float(v.max()), optimised)
    bins = np.linspace(lo, hi + 1e-12, 31) if hi > lo else 10
    ax.hist(v, bins=bins, color="#7f9fbf", edgecolor="white", label=f"{len(v)} random systems")
    ax.axvline(float(np.median(v)), color="#444444", ls="--", lw=1.2, label=f"median {np.median(v):.4f}")
    ax.axvline(optimised, color=OPT_COLOUR, lw=2.2, label=f"optimised {optimised:.4f}")
    if run_objective is not None and abs(run_objective - optimised) > 1e-12:
        ax.axvline(run_objective, color="#ff7f0e", lw=1.6, ls=":", label=f"run's system {run_objective:.4f}")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("systems")
    ax.set_title(plain(title), fontsize=10)
    ax.legend(fontsize=8, loc="upper left")
    return _png(fig)


def robust_png(values: dict[str, Sequence[float]], title: str, *, xlabel: str = "objective (observed weight)") -> bytes:
    """Overlaid histograms of systems' objectives over sampled installations, means and 10th percentiles marked.

    Parameters
    ----------
    values : dict of str to (S,) float64
        Per system (``robust``, ``nominal``) its objective in each installation.
    title : str
    """
    from camplace.robust.p10 import order_p10

    colours = {"robust": OPT_COLOUR, "nominal": "#1f77b4"}
    arrays = {k: np.asarray(v, dtype=np.float64) for k, v in values.items() if len(v)}
    fig = _figure(6.4, 3.4)
    ax = fig.add_subplot()
    allv = np.concatenate(list(arrays.values())) if arrays else np.zeros(1)
    lo, hi = float(allv.min()), float(allv.max())
    bins = np.linspace(lo, hi + 1e-12, 31) if hi > lo else 10
    for name, v in arrays.items():
        c = colours.get(name, "#7f7f7f")
        ax.hist(v, bins=bins, color=c, alpha=0.45, edgecolor="white", label=f"{name} system ({len(v)} installations)")
        ax.axvline(float(v.mean()), color=c, lw=2.0, label=f"{name} mean {v.mean():.4f}")
        ax.axvline(order_p10(v), color=c, lw=1.4, ls="--", label=f"{name} 10th percentile {order_p10(v):.4f}")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("installations")
    ax.set_title(plain(title), fontsize=10)
    ax.legend(fontsize=7, loc="upper left")
    return _png(fig)


def sampler_png(study, run_point: tuple[str, int, float] | None = None) -> bytes:
    """Best objective against candidate positions (left) and discrepancy (right), per sampler.

    Parameters
    ----------
    study : camplace.report.study.SamplerStudy
    run_point : (sampler, n_positions, objective) or None
        The run itself, marked with a star.
    """
    fig = _figure(10.0, 3.6)
    ax1, ax2 = fig.subplots(1, 2)
    for s in study.samplers:
        n, obj = study.series(s, "objective")
        _, disc = study.series(s, "discrepancy")
        c = SAMPLER_COLOURS.get(s, None)
        ax1.plot(n, obj, "o-", color=c, label=s)
        ok = np.isfinite(disc)
        ax2.plot(n[ok], disc[ok], "o-", color=c, label=s)
    if run_point is not None:
        ax1.plot([run_point[1]], [run_point[2]], "*", ms=14, color="black", label=f"run ({run_point[0]})")
    ax1.set_xscale("log")
    ax1.set_xlabel("candidate positions")
    ax1.set_ylabel("best objective (observed weight)")
    ax1.set_title("best k-camera objective vs candidates", fontsize=10)
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=8)
    ax2.set_xscale("log")
    ax2.set_yscale("log")
    ax2.set_xlabel("candidate positions")
    ax2.set_ylabel(f"discrepancy ({study.discrepancy_method}, unit cube)")
    ax2.set_title("discrepancy of the positions (lower = more uniform)", fontsize=10)
    ax2.grid(alpha=0.3, which="both")
    ax2.legend(fontsize=8)
    return _png(fig)


def cones_png(panels: Sequence[tuple[str, np.ndarray, np.ndarray]], extent: tuple[float, float, float, float],
              target_box: tuple[float, float, float, float] | None = None, vmax: int | None = None) -> bytes:
    """Vision-cone density panels stacked vertically (top view, x right, y up).

    Parameters
    ----------
    panels : sequence of (title, density (ny, nx) int, camera positions (k, 3))
    extent : (xmin, xmax, ymin, ymax)
    target_box : (xmin, xmax, ymin, ymax) or None
        Drawn as a white outline.
    vmax : int or None
        Colour scale maximum (default: the largest k).
    """
    xmin, xmax, ymin, ymax = extent
    aspect = (ymax - ymin) / max(xmax - xmin, 1e-9)
    width = 10.0
    panel_h = max(1.1, min(4.0, width * 0.82 * aspect + 0.55))
    fig = _figure(width, panel_h * len(panels) + 0.3)
    axes = np.atleast_1d(fig.subplots(len(panels), 1, squeeze=False)[:, 0])
    vmax = vmax or max(int(p[2].shape[0]) for p in panels)
    im = None
    for ax, (title, dens, pos) in zip(axes, panels):
        im = ax.imshow(dens, origin="lower", extent=extent, cmap="magma", vmin=0, vmax=vmax, interpolation="nearest", aspect="equal")
        ax.plot(pos[:, 0], pos[:, 1], "o", ms=6, mfc="#00e5ff", mec="black")
        if target_box is not None:
            tx0, tx1, ty0, ty1 = target_box
            ax.plot([tx0, tx1, tx1, tx0, tx0], [ty0, ty0, ty1, ty1, ty0], color="white", lw=1.2)
        ax.set_title(plain(title), fontsize=9, loc="left")
        ax.set_ylabel("y (m)", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[-1].set_xlabel("x (m)", fontsize=8)
    if im is not None:
        cb = fig.colorbar(im, ax=list(axes), shrink=0.9, pad=0.01, ticks=range(0, vmax + 1))
        cb.set_label("cameras whose FoV wedge covers the cell", fontsize=8)
    return _png(fig)


def legacy_scatter_png(groups: Sequence[tuple[str, np.ndarray, np.ndarray]], optimised: tuple[float, float] | None, title: str,
                       samplers: Sequence[str] | None = None) -> bytes:
    """Legacy score (x) against the ray-cast objective (y), one colour per campaign.

    Parameters
    ----------
    groups : sequence of (label, legacy scores (n,), objectives (n,))
    optimised : (legacy score, objective) of the optimised system, or None
    samplers : sequence of str or None
        Each group's sampler: its colour, as in the sampler figure (first use only; repeats get others).
    """
    fig = _figure(6.4, 4.2)
    ax = fig.add_subplot()
    palette = ["#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22"]
    used: set[str] = set()
    for i, (label, leg, obj) in enumerate(groups):
        s = samplers[i] if samplers is not None and i < len(samplers) else None
        colour = SAMPLER_COLOURS.get(s) if s is not None and s not in used else None
        if s is not None:
            used.add(s)
        ax.scatter(leg, obj, s=12, alpha=0.6, color=colour or palette[i % len(palette)], label=plain(label))
    if optimised is not None:
        ax.plot([optimised[0]], [optimised[1]], "*", ms=16, color="black", label="optimised system")
    ax.set_xlabel("legacy score (thesis Algorithm 2, literal)")
    ax.set_ylabel("objective (ray-cast observed weight)")
    ax.set_title(plain(title), fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _png(fig)


def light_curves_png(curves: dict[str, tuple[np.ndarray, np.ndarray]], title: str) -> bytes:
    """Observed weight per frame, one line per camera.

    Parameters
    ----------
    curves : dict of camera name -> (frames (n,), observed weight (n,))
    """
    fig = _figure(6.4, 3.4)
    ax = fig.add_subplot()
    from matplotlib.ticker import MaxNLocator

    for name, (f, w) in curves.items():
        ax.plot(f, w, "o-", ms=4, label=plain(name))
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("frame")
    ax.set_ylabel("observed weight")
    ax.set_title(plain(title), fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return _png(fig)
