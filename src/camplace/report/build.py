"""``report.html``: one self-contained page about a run, its campaigns, the samplers and validation.

Everything is embedded (images as base64 ``data:`` URIs, CSS inline, the 3D view's plotly.js inline:
:mod:`camplace.report.run_scene`), and a Content-Security-Policy forbids the page any other resource,
so it opens offline in any browser.
Every string that comes from a file or the user is escaped with :func:`html.escape`.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from camplace._io import write_text_atomic
from camplace.errors import CamplaceError
from camplace.report.markup import _img, _num, _table, _vec, esc

log = logging.getLogger(__name__)

__all__ = ["write_report", "run_report_bundle", "percentile_of", "BUNDLE_SAMPLERS", "BUNDLE_SYSTEMS"]

BUNDLE_SAMPLERS = ("uniform", "chaotic")
BUNDLE_SYSTEMS = 200
REPORT_NAME = "report.html"  # the report's default file in the run folder
THUMB_WIDTH_PX = 420
MAX_RENDERS = 12

CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,'DejaVu Sans',sans-serif;margin:0;background:#f4f5f7;color:#1d2330}
main{max-width:1120px;margin:0 auto;padding:20px 28px 60px;background:#fff}
h1{font-size:1.6em;margin:.3em 0 .1em}h2{font-size:1.25em;border-bottom:2px solid #d0d5de;padding-bottom:4px;margin-top:1.8em}
h3{font-size:1.05em;margin:1.2em 0 .4em}
table{border-collapse:collapse;margin:.5em 0 1em;font-size:.88em}
th,td{border:1px solid #d0d5de;padding:3px 8px;text-align:right}th{background:#eef1f5}
td.l,th.l{text-align:left}
figure{margin:.6em 0 1.2em}figure img{max-width:100%;height:auto;border:1px solid #e2e5ea}
figcaption{font-size:.85em;color:#4a5263;margin-top:3px}
.grid{display:flex;flex-wrap:wrap;gap:12px}.grid figure{margin:0;flex:0 1 420px}
.note{background:#f0f6ff;border-left:4px solid #3b7dd8;padding:6px 12px;margin:.8em 0;font-size:.92em}
.ok{background:#eefaf0;border-left:4px solid #2e9d46;padding:6px 12px;margin:.8em 0}
.bad{background:#fff0f0;border-left:4px solid #d33;padding:6px 12px;margin:.8em 0}
.muted{color:#6b7385;font-size:.88em}code{background:#f1f3f6;padding:0 3px}
nav a{margin-right:12px}
"""

CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'; script-src 'unsafe-inline'"  # scripts: the 3D view


def percentile_of(values: np.ndarray, x: float, tie: float = 1e-12) -> float:
    """Percent of ``values`` that are <= ``x`` (+ ``tie``)."""
    v = np.asarray(values, dtype=np.float64)
    return float(100.0 * np.mean(v <= x + tie)) if len(v) else float("nan")


def _heading_pitch_deg(R: np.ndarray) -> tuple[float, float]:
    """Heading of the optical axis in the x-y plane (deg from +x towards +y) and its elevation (deg)."""
    f = np.asarray(R, dtype=np.float64)[:, 2]
    return math.degrees(math.atan2(f[1], f[0])), math.degrees(math.asin(max(-1.0, min(1.0, f[2]))))


def _thumbnail(img: np.ndarray, width: int = THUMB_WIDTH_PX) -> bytes:
    """Downscaled PNG of an image (float [0, 1] or uint8/uint16; gray or BGR)."""
    import cv2

    a = np.asarray(img)
    if a.dtype != np.uint8:
        a = np.clip(np.rint(np.asarray(a, dtype=np.float64) * (255.0 if a.dtype.kind == "f" else 255.0 / np.iinfo(a.dtype).max)), 0, 255).astype(np.uint8)
    h, w = a.shape[:2]
    if w > width:
        a = cv2.resize(a, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".png", a)
    if not ok:  # pragma: no cover - OpenCV always encodes uint8
        raise CamplaceError("could not encode a thumbnail as PNG")
    return buf.tobytes()


# --------------------------------------------------------------------------------------------------
# sections


def _instance_section(run) -> str:
    from camplace.report.legacy import legacy_target

    inst, sol = run.instance, run.solution
    cam = inst.camera
    lt = legacy_target(inst)
    def words(cam) -> str:
        return (f"{cam.width_px} x {cam.height_px} px, sensor {cam.sensor_width_mm} x {cam.sensor_height_mm} mm, "
                f"f = {cam.focal_length_mm} mm, FoV {cam.fov_x_deg:.1f} x {cam.fov_y_deg:.1f} deg, depth {cam.near_m}..{cam.far_m} m")

    team = getattr(inst, "team", None)
    if team is None:
        cam_rows = [("camera", words(cam)), ("camera volume", f"{_vec(inst.volume.min_m, 2)} .. {_vec(inst.volume.max_m, 2)} m")]
    else:
        counts = lambda m: f"{m.min_count}..{m.max_count}" if m.max_count is not None else f"at least {m.min_count}"  # noqa: E731
        cam_rows = [(f"camera model {m.name}", f"{words(m)}; cost {m.cost:g}, count {counts(m)}") for m in team.models]
        cam_rows.append(("where cameras may stand", f"{len(team.volumes)} volume(s), {len(team.mounts)} mount surface(s), "
                         f"{len(team.keepouts)} keep-out(s); bounding box {_vec(inst.volume.min_m, 2)} .. {_vec(inst.volume.max_m, 2)} m"))
        cam_rows.append(("team budget and zones", (f"budget {team.budget:g}" if team.budget is not None else "no budget") + "; "
                         + (", ".join(f"{z.name} ({z.min_cameras}{'..' + str(z.max_cameras) if z.max_cameras is not None else '+'})"
                                      for z in team.zones) or "no zones")
                         + (" (enforced by the solver)" if (getattr(sol, "team", None) or {}).get("enforced")
                            else " (not enforced: see the notes)")))
    rows = [
        ("instance", inst.name),
        ("source", inst.source or "–"),
        ("cameras to place (k)", len(sol.cameras)),
        *cam_rows,
        ("frames", f"{len(inst.frames)} (event centre aims: {len(run.aims)})"),
        ("target (top view)", f"x {lt.x_t_m:.3f}..{lt.x_t_m + lt.width_m:.3f} m, y {lt.y_t_m:.3f}..{lt.y_t_m + lt.height_m:.3f} m"),
        ("quality", f"{inst.quality.mode}, max incidence {inst.quality.max_incidence_deg} deg"),
        ("lit points only (require_light)", _require_light_words(inst.quality.require_light)),
        ("run", f"sampler {sol.sampler}, seed {sol.seed}, {sol.n_candidates:,} candidates x {sol.n_points:,} points, engine {sol.engine}"),
        ("event mode", f"{getattr(sol, 'event_mode', 'all')} (rows weighted by {'every frame' if getattr(sol, 'event_mode', 'all') == 'all' else 'the peak frame alone'})"),
        ("timings", ", ".join(f"{k} {v:.2f} s" for k, v in sol.timings_s.items() if "." not in str(k))),
    ]
    warn = "".join(f"<p class='bad'>run warning: {esc(w)}</p>" for w in (getattr(sol, "warnings", None) or []))
    return "<h2 id='instance'>Instance and run</h2>" + _table(None, rows, left=2) + warn


def _require_light_words(require_light: bool) -> str:
    """What ``[quality] require_light`` means for the report's reader."""
    if require_light:
        return ("true: a point counts as observed only where the light reaches it (its surface faces the light and "
                "nothing shadows it), so the unlit side of the target stays unobserved by any placement")
    return "false: lit and unlit points count alike"


def _objective_words(sol) -> str:
    """What the report's objective measures, in words (the run's mode; :func:`scoring_of`)."""
    from camplace.report.campaign import scoring_of

    sc = scoring_of(sol)
    if sc["mode"] == "quality":
        return "weight x best observation quality"
    if sc["mode"] == "multiview":
        angle = f", two of them >= {sc['min_angle_deg']:g} deg apart" if sc["min_angle_deg"] is not None else ""
        return f"weight seen by >= {sc['views']} cameras{angle}"
    if getattr(sol, "mode", "maxcover") == "setcover":
        return f"observed weight of the {len(sol.cameras)} cameras that cover it all (setcover, {sol.status})"
    return "observed weight"


def setcover_rows(sol) -> list[tuple[str, str]]:
    """(heading, text) rows saying how many cameras a setcover run needs and how far that is
    proven: the number of new cameras, the lower bound on it, the status, points no candidate sees.

    ``sol`` is a :class:`camplace.pipeline.Solution` of mode ``setcover`` (objective = new cameras,
    bound = lower bound on their number, ``solver_stats.uncoverable_points``).
    """
    opts = getattr(sol, "options", None) or {}
    stats = getattr(sol, "solver_stats", None) or {}
    frac = opts.get("required_fraction")
    n_fixed = len(opts.get("fixed") or [])
    new = len(sol.cameras) - n_fixed
    what = ("every point a candidate sees" if frac is None or float(frac) >= 1.0
            else f"{100 * float(frac):g} % of the weight the candidates see")
    fixed = f" besides the {n_fixed} fixed ones" if n_fixed else ""
    bound = float(sol.bound)
    if not math.isfinite(bound):
        proof = "no lower bound"
    elif sol.status == "optimal" or bound >= float(sol.objective) - 1e-9:
        proof = f"{bound:g}: no fewer cameras can do it (optimal)"
    else:
        proof = (f"{bound:g} ({sol.status}: at most {float(sol.objective) - bound:g} camera(s) more than the fewest "
                 f"possible; raise --time-limit to close the gap)")
    rows = [("cameras that cover it all", f"{new} new camera(s){fixed} cover {what}"),
            ("lower bound on the number of cameras", proof)]
    unc = stats.get("uncoverable_points")
    if unc:
        rows.append(("points no candidate sees", f"{int(unc):,} (weight {float(stats.get('uncoverable_weight', 0.0)):.4g}; "
                                                  "not counted, no camera could cover them)"))
    return rows


def _system_section(run, comp) -> str:
    from camplace.report.campaign import scoring_of

    sol = run.solution
    w_total = float(run.weights.sum())
    if getattr(sol, "mode", "maxcover") == "setcover":
        # the run's proof is about the number of cameras; the weight they observe has no bound of its own
        status = sol.status
        proof = "".join(f"<tr><th class='l'>{esc(h)}</th><td class='l'>{esc(t)}</td></tr>" for h, t in setcover_rows(sol))
    else:
        status = comp.status
        proof = (f"<tr><th class='l'>proven bound</th><td class='l'>{_num(comp.bound, 6)}</td></tr>"
                 f"<tr><th class='l'>gap</th><td class='l'>"
                 f"{_num(100 * comp.gap if comp.gap is not None and math.isfinite(comp.gap) else None, 4)} %</td></tr>")
    head = (
        f"<h2 id='system'>Optimised system</h2>"
        f"<table><tbody>"
        f"<tr><th class='l'>status</th><td class='l'>{esc(status)}</td></tr>"
        f"<tr><th class='l'>objective ({esc(_objective_words(sol))})</th><td class='l'>{_num(comp.objective, 6)}</td></tr>"
        f"<tr><th class='l'>{'share of the event' if scoring_of(sol)['mode'] != 'maxcover' else 'coverage'}</th>"
        f"<td class='l'>{_num(100 * comp.objective / w_total if w_total > 0 else 0, 2)} % of the event</td></tr>"
        + proof +
        f"<tr><th class='l'>chosen from</th><td class='l'>{comp.n_columns:,} candidate poses ({esc(comp.note)})</td></tr>"
        f"</tbody></table>"
    )
    rows = []
    team = getattr(run.instance, "team", None) is not None
    for n, c in enumerate(comp.cameras, start=1):
        hd, el = _heading_pitch_deg(np.array(c["rotation"]))
        model = (c.get("model", ""),) if team else ()
        rows.append((n, *model, c["source"], _vec(c["position"]), _vec(c["aim"]), f"{hd:.1f}", f"{el:.1f}", _num(c["observed_weight"], 4)))
    table = _table(["camera", *(["model"] if team else []), "source", "position (m)", "aim (m)", "heading (deg)", "elevation (deg)",
                    "observed alone"], rows, left=2)
    extra = ""
    if comp.method == "union":
        extra = (f"<p class='note'>The run's own system ({_num(comp.run_objective, 6)}, status {esc(sol.status)} over its "
                 f"{sol.n_candidates:,} candidates) was improved on by re-solving over the union with the campaign cameras.</p>")
    return head + table + extra


def _robust_section(run) -> str:
    """Robust runs: both systems' objective over fresh installations (empty for nominal runs)."""
    from camplace.report.figures import robust_png

    r = getattr(run.solution, "robust", None)
    if not r or "out_of_sample" not in r:
        return ""
    st, oos, ins = r["settings"], r["out_of_sample"], r.get("in_sample", {})
    rows = [(name, _num(ins.get(name, {}).get("mean"), 6), _num(ins.get(name, {}).get("p10"), 6), _num(oos[name]["mean"], 6),
             _num(oos[name]["p10"], 6), _num(oos[name]["min"], 6)) for name in ("robust", "nominal") if name in oos]
    png = robust_png({name: oos[name].get("values", []) for name in ("robust", "nominal") if name in oos},
                     f"{st['eval_scenarios']} fresh installations, sigma {st['position_sigma_m']:g} m / {st['rotation_sigma_deg']:g} deg")
    return (
        "<h2 id='robust'>Installation error</h2>"
        f"<p class='note'>The system was chosen for its {esc(st['objective'])} objective over {st['scenarios']} sampled installations "
        f"(every camera off by N(0, {st['position_sigma_m']:g} m) per axis and turned by N(0, {st['rotation_sigma_deg']:g} deg) "
        "per rotation-vector component), beside the nominal optimum (exact poses). The other sections score poses as planned.</p>"
        + _table(["system", "sampled mean", "sampled p10", "fresh mean", "fresh p10", "fresh worst"], rows)
        + _img(png, "objective over installations", "Objective of both systems on fresh installations (another seed)")
    )


def _campaign_section(run, comp, campaigns) -> tuple[str, dict]:
    from camplace.report.figures import histogram_png

    if not campaigns:
        return ("<h2 id='campaigns'>Campaigns</h2><p class='muted'>No campaign folder (holding campaign.json) in this "
                "folder: run <code>camplace campaign INSTANCE --systems 200 --sampler uniform -o OUTDIR/campaign-uniform</code>.</p>"), {}
    top = max(float(c.objective.max()) for c in campaigns)
    cls = "ok" if comp.holds else "bad"
    verdict = "holds" if comp.holds else "DOES NOT HOLD (the solver stopped before proving optimality; raise --time-limit)"
    parts = [
        "<h2 id='campaigns'>Campaigns: optimised against random systems</h2>",
        "<p class='note'><b>How the comparison is made.</b> Every system is scored with the solver's objective "
        "(weight of the event points observed by at least one of its cameras) on the <i>same rows</i>: the run's points "
        "(a campaign is accepted only when its problem fingerprint — instance, seed, points — equals the run's). "
        "Campaign cameras stand at fresh positions, so the comparison uses the union matrix: the run's candidate columns "
        "side by side with all campaign camera columns. When the run's system already scores at least as well as every "
        "campaign system it is the optimised system; otherwise the k-camera problem is re-solved over the union of the "
        "run's candidates and the campaign cameras, whose proven optimum cannot score below any campaign system "
        "(each of them is a feasible choice there).</p>",
        f"<p class='{cls}'>Guarantee — the optimised system ({_num(comp.objective, 6)}) scores at least as well as every "
        f"campaign system (best {_num(top, 6)}) on the same matrix: <b>{esc(verdict)}</b>. Method: {esc(comp.method)}; {esc(comp.note)}.</p>",
    ]
    rows = []
    stats = {}
    for c in campaigns:
        v = c.objective
        pct = percentile_of(v, comp.objective)
        med = float(np.median(v))
        best = float(v.max())
        stats[c.name] = {"percentile": pct, "ratio_best": comp.objective / best if best > 0 else None,
                         "ratio_median": comp.objective / med if med > 0 else None}
        rows.append((c.name, c.sampler, c.seed, c.n_systems, _num(v.min()), _num(med), _num(v.mean()), _num(best),
                     f"{pct:.1f}", _num(stats[c.name]["ratio_best"], 3), _num(stats[c.name]["ratio_median"], 3)))
    parts.append(_table(["campaign", "sampler", "seed", "systems", "min", "median", "mean", "best",
                         "optimised percentile", "optimised / best", "optimised / median"], rows, left=2))
    figs = []
    for c in campaigns:
        png = histogram_png(c.objective, comp.objective, f"{c.name}: {c.n_systems} random {c.k}-camera systems ({c.sampler})",
                            run_objective=comp.run_objective)
        s = stats[c.name]
        figs.append(_img(png, f"objective histogram of {c.name}",
                         f"{esc(c.name)}: the optimised system is at percentile {s['percentile']:.1f}, "
                         f"{_num(s['ratio_best'], 3)} x the best and {_num(s['ratio_median'], 3)} x the median random system."))
    parts.append("<div class='grid'>" + "".join(figs) + "</div>")
    return "".join(parts), stats


def _sampler_section(run, study) -> str:
    from camplace.report.figures import sampler_png

    if study is None and getattr(run.instance, "team", None) is not None:
        return ("<h2 id='samplers'>Samplers</h2><p class='muted'>Sampler study skipped: its ladders of candidate positions "
                "are not defined for a camera team (pose x model columns) yet.</p>")
    if study is None:
        return "<h2 id='samplers'>Samplers</h2><p class='muted'>Sampler study skipped (--no-sampler-study).</p>"
    sol = run.solution
    a = len(run.aims)
    png = sampler_png(study, (sol.sampler, sol.n_candidates // a, sol.objective))
    rows = []
    for s in study.samplers:
        rs = sorted((r for r in study.rows if r["sampler"] == s), key=lambda r: r["n_positions"])
        last = rs[-1]
        rows.append((s, last["n_positions"], _num(last["objective"], 6), last["status"], _num(last["discrepancy"], 6),
                     " / ".join(_num(r["objective"], 4) for r in rs)))
    ladder = ", ".join(str(n) for n in study.ladder)
    return (
        "<h2 id='samplers'>Samplers: best objective against candidates, and discrepancy</h2>"
        f"<p class='note'>Each sampler draws the run's number of candidate positions with the run's candidate seed stream "
        f"(the run's own sampler reproduces its candidates). Sequences are nested, so the first n positions give the "
        f"n-candidate problem; each is solved on the run's rows (ladder: {esc(ladder)}; time limit {study.time_limit_s:g} s "
        f"per solve). Discrepancy: <code>scipy.stats.qmc.discrepancy(method='{esc(study.discrepancy_method)}')</code> of the "
        f"positions mapped to the unit cube.</p>"
        + _img(png, "best objective and discrepancy per sampler", "Left: best objective found with the first n candidate positions. Right: discrepancy of those positions.")
        + _table(["sampler", "positions", "best objective", "status", "discrepancy", "objective along the ladder"], rows)
    )


def _pick_five(c) -> list[tuple[int, str]]:
    order = np.argsort(c.objective, kind="stable")
    n = len(order)
    picks, out = [(n - 1, "best"), (int(round(0.75 * (n - 1))), "75th percentile"), (int(round(0.5 * (n - 1))), "median"),
                  (int(round(0.25 * (n - 1))), "25th percentile"), (0, "worst")], []
    seen = set()
    for rank, label in picks:
        s = int(order[rank])
        if s not in seen:
            seen.add(s)
            out.append((s, label))
    return out


def _cones_section(run, comp, campaigns) -> str:
    from camplace.report.cones import cone_density, cone_grid
    from camplace.report.figures import cones_png
    from camplace.report.legacy import legacy_target

    inst = run.instance
    grid = cone_grid(inst)
    fov = math.radians(inst.camera.fov_x_deg)
    rng_m = float(inst.camera.far_m)

    def density(pos: np.ndarray, rot: np.ndarray, models) -> np.ndarray:
        """Cone density, each camera with its model's FoV and far limit."""
        if models is None or getattr(inst, "team", None) is None:
            return cone_density(pos, rot, fov, rng_m, grid)
        models = np.asarray(models)
        return sum(cone_density(pos[models == j], rot[models == j], math.radians(m.fov_x_deg), float(m.far_m), grid)
                   for j, m in enumerate(inst.cameras))

    pos = np.array([c["position"] for c in comp.cameras])
    rot = np.array([c["rotation"] for c in comp.cameras])
    own_models = [c.get("model_index", 0) for c in comp.cameras]
    panels = [(f"optimised system (objective {comp.objective:.4f})", density(pos, rot, own_models), pos)]
    if campaigns:
        c = campaigns[0]
        for s, label in _pick_five(c):
            panels.append((f"{c.name} system {s + 1}: {label} (objective {c.objective[s]:.4f})",
                           density(c.positions[s], c.rotations[s], None if c.model is None else c.model[s]), c.positions[s]))
    lt = legacy_target(inst)
    png = cones_png(panels, grid.extent, (lt.x_t_m, lt.x_t_m + lt.width_m, lt.y_t_m, lt.y_t_m + lt.height_m))
    wedge = (f"half-angle {inst.camera.fov_x_deg / 2:.1f} deg, radius = far limit {rng_m:g} m" if getattr(inst, "team", None) is None
             else "half-angle and radius those of its camera model: " + ", ".join(
                 f"{m.name} {m.fov_x_deg / 2:.1f} deg, {m.far_m:g} m" for m in inst.cameras))
    return (
        "<h2 id='cones'>Vision-cone density (top view)</h2>"
        f"<p class='note'>As the thesis's Figure 7.18: on an x-y grid over the camera volume, the number of cameras whose "
        f"horizontal field-of-view wedge (apex at the camera, heading of its optical axis, "
        f"{wedge}) covers each cell; camera pitch is ignored. "
        f"White outline: the target. The campaign systems are the best, 75th percentile, median, 25th percentile and worst "
        f"of the first campaign.</p>"
        + _img(png, "vision-cone density heatmaps", "Vision-cone density of the optimised system (top) and five campaign systems.")
    )


def _legacy_section(run, comp, campaigns) -> str:
    from scipy.stats import spearmanr

    from camplace.report.figures import legacy_scatter_png
    from camplace.report.legacy import corrected_fov_rad, legacy_system_score, legacy_target, printed_fov

    head = "<h2 id='legacy'>The thesis's legacy score against the ray-cast objective</h2>"
    cam = run.instance.camera
    fov_printed = math.degrees(printed_fov(cam.sensor_width_mm, cam.focal_length_mm))
    fov_meant = math.degrees(corrected_fov_rad(cam.sensor_width_mm, cam.focal_length_mm))
    quirks = (
        "<p class='note'>The legacy score is the thesis's Algorithm 2 (section 5.4.2) implemented literally, summed over a "
        "system's cameras: <code>d = |target − camera|</code> (2D), <code>fov = 2·arctan(sensorsize/2·focallength) + ω</code> "
        "as printed, a square coverage box <code>x_c ± fov·2</code>, its overlap area <code>a</code> with the target box "
        "<code>[x_t, x_t+W] × [y_t, y_t+H]</code>, and <code>δ = d + a</code>. Quirks: it is 2D only (no height, "
        "orientation or occlusion); the printed FoV formula is garbled (<code>2·arctan(sensor/(2f))</code> was meant: "
        f"{fov_printed:.0f}° instead of {fov_meant:.0f}° here); radians and degrees are mixed (ω); an angle is used as a length; metres are added to "
        "square metres; and, once the box holds the target, the score grows with the distance to the target.</p>"
    )
    if not campaigns:
        return head + quirks + "<p class='muted'>No campaign to rank.</p>"
    groups, rows = [], []
    all_l, all_o = [], []
    for c in campaigns:
        groups.append((c.name, c.legacy_score, c.objective))
        all_l.append(c.legacy_score)
        all_o.append(c.objective)
        rho, p = _spearman(c.legacy_score, c.objective, spearmanr)
        best_leg = int(np.argmax(c.legacy_score))
        rows.append((c.name, c.n_systems, _num(rho, 3), _num(p, 4), int(best_leg) + 1, _num(c.objective[best_leg], 4),
                     f"{percentile_of(c.objective, float(c.objective[best_leg])):.1f}"))
    L, O = np.concatenate(all_l), np.concatenate(all_o)
    rho_all, p_all = _spearman(L, O, spearmanr)
    rows.append(("all campaigns", len(L), _num(rho_all, 3), _num(p_all, 4), "", "", ""))
    pos = np.array([c["position"] for c in comp.cameras])
    opt_leg = float(legacy_system_score(pos[None], legacy_target(run.instance))[0])
    png = legacy_scatter_png(groups, (opt_leg, comp.objective), f"legacy score vs objective (Spearman rho = {_num(rho_all, 3)})",
                             samplers=[c.sampler for c in campaigns])
    return (
        head + quirks
        + _table(["campaign", "systems", "Spearman rho", "p-value", "legacy's best system", "its objective", "its objective percentile"], rows)
        + _img(png, "legacy score against objective", f"Each dot is a random system. Optimised system: legacy score {opt_leg:.3f}.")
    )


def _spearman(a, b, spearmanr) -> tuple[float | None, float | None]:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if len(a) < 2 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return None, None
    r = spearmanr(a, b)
    return float(r.statistic), float(r.pvalue)


# --------------------------------------------------------------------------------------------------
# validation


def _find_validation(outdir: Path) -> list[Path]:
    found = []
    if (outdir / "validation.json").is_file():
        found.append(outdir / "validation.json")
    for p in sorted(outdir.iterdir()):
        if p.is_dir() and (p / "validation.json").is_file():
            found.append(p / "validation.json")
    return found


def _read_light_curves(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Curves of a ``light_curves.csv`` (camera, frame, observed_weight[, candidate, ...]) keyed by a label.

    Cameras are labelled by their candidate column when the file has one (as ``camplace run``
    writes it), else by the ``camera`` value as written.
    """
    try:
        rows = list(csv.DictReader(path.read_text().splitlines()))
    except OSError as exc:
        raise CamplaceError(f"{path}: cannot read ({exc.strerror})") from None
    curves: dict[str, list[tuple[float, float]]] = {}
    for i, r in enumerate(rows, start=2):
        try:
            label = f"candidate {int(float(r['candidate']))}" if r.get("candidate") not in (None, "") else f"camera {r['camera']}"
            curves.setdefault(label, []).append((float(r["frame"]), float(r["observed_weight"])))
        except (KeyError, TypeError, ValueError):
            raise CamplaceError(f"{path}:{i}: the header must be camera,frame,observed_weight with numbers below") from None
    out = {}
    for name, pts in curves.items():
        a = np.array(sorted(pts))
        out[name] = (a[:, 0], a[:, 1])
    return out


def _matrix_light_curves(run, comp) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Observed weight per frame of each of the run's chosen cameras (from the visibility matrix)."""
    frames = run.points.frame
    w = run.points.weight  # the event's own weights (not the solver's, which may keep the peak frame only)
    nf = int(frames.max()) + 1 if len(frames) else 0
    out = {}
    for n, c in enumerate(run.solution.cameras, start=1):
        col = np.asarray((run.matrix[:, int(c["candidate"])] > 0).toarray()).ravel()
        out[f"candidate {int(c['candidate'])}"] = (np.arange(nf), np.bincount(frames[col], weights=w[col], minlength=nf))
    return out


def _validation_section(run, comp) -> str:
    from camplace.report.figures import light_curves_png

    outdir = run.outdir
    parts = ["<h2 id='validation'>Validation: renders, detections and simulation against photographs</h2>"]
    have = False
    rjson = outdir / "render" / "render.json"
    if rjson.is_file():
        have = True
        parts.append(_renders_html(rjson, run.instance))
    for vpath in _find_validation(outdir):
        have = True
        parts.append(_validation_html(vpath))
    lc_paths = [p / "light_curves.csv" for p in [outdir, outdir / "render", *[v.parent for v in _find_validation(outdir)]]]
    lc = next((p for p in lc_paths if p.is_file()), None)
    if lc is not None:
        have = True
        parts.append("<h3>Light curves</h3>" + _img(light_curves_png(_read_light_curves(lc), f"light curves ({lc.name})"),
                                                    "light curves", f"Observed weight per frame, from {esc(lc.relative_to(outdir))}."))
    elif len(run.instance.frames) > 1:
        parts.append("<h3>Light curves</h3>" + _img(light_curves_png(_matrix_light_curves(run, comp), "observed weight per frame (visibility matrix)"),
                                                    "light curves", "Observed weight per frame of each of the run's cameras, from the visibility matrix."))
    if not have:
        parts.append("<p class='muted'>Validation has not run: <code>camplace render OUTDIR</code> and "
                     "<code>camplace validate OUTDIR -o OUTDIR/validation</code> add rendered views, detected bounding boxes "
                     "and the simulation-against-photograph figures here.</p>")
    return "".join(parts)


def _renders_html(rjson: Path, instance=None) -> str:
    """The rendered views with Algorithm 3's box; with ``require_light`` the detection floors at an
    unlit surface's level, as validate's (:func:`camplace.validation.workflow.observable_detection`)."""
    import cv2

    from camplace.validation.detect import DetectionSettings, detect_target
    from camplace.validation.physical import unlit_level
    from camplace.validation.render import read_image

    lit_only = instance is not None and instance.quality.require_light
    detection = DetectionSettings(min_level=unlit_level(None) if lit_only else 0.0)

    try:
        manifest = json.loads(rjson.read_text())
        images = list(manifest["images"])
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise CamplaceError(f"{rjson}: cannot read the render manifest ({exc}); re-run 'camplace render'") from None
    folder = rjson.parent
    figs = []
    for rec in images[:MAX_RENDERS]:
        img_path = folder / str(rec["image"])
        bg_path = folder / str(rec.get("background", ""))
        if not img_path.is_file():
            continue
        img = read_image(img_path)
        bg = read_image(bg_path) if rec.get("background") and bg_path.is_file() else None
        det = detect_target(img, bg, detection)
        vis = np.clip(np.asarray(img, dtype=np.float64) * 255.0, 0, 255).astype(np.uint8)
        if vis.ndim == 2:
            vis = cv2.cvtColor(vis, cv2.COLOR_GRAY2BGR)
        thick = max(2, vis.shape[1] // 300)
        if det.bbox_xywh is not None:
            x, y, w, h = (int(v) for v in det.bbox_xywh)
            cv2.rectangle(vis, (x, y), (x + w - 1, y + h - 1), (0, 220, 0), thick)
        box = "no target detected" if det.bbox_xywh is None else f"box x={det.bbox_xywh[0]}, y={det.bbox_xywh[1]}, {det.bbox_xywh[2]} x {det.bbox_xywh[3]} px"
        figs.append(_img(_thumbnail(vis), f"render {rec['image']}",
                         f"{esc(rec['image'])}: {esc(rec.get('target_px', '?'))} predicted target px; detected {det.area_px} px, {esc(box)}"))
    more = f"<p class='muted'>{len(images) - MAX_RENDERS} more views in render/ are not shown.</p>" if len(images) > MAX_RENDERS else ""
    return ("<h3>Rendered views with detected bounding boxes</h3>"
            "<p class='muted'>Each chosen camera's ray-cast view (render/); the green box is the target found by the "
            "thesis's Algorithm 3 (difference with the background render, Otsu threshold"
            + ("; lit pixels only: the instance requires light" if lit_only else "") + ").</p>"
            + "<div class='grid'>" + "".join(figs) + "</div>" + more)


def _validation_html(vpath: Path) -> str:
    from camplace.validation.render import read_image

    try:
        rep = json.loads(vpath.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise CamplaceError(f"{vpath}: cannot read the validation report ({exc}); re-run 'camplace validate'") from None
    folder = vpath.parent
    cams = rep.get("cameras", []) or []
    rows = [(c.get("name", "?"), c.get("system", ""), c.get("predicted_px"), c.get("detected_px"), _num(c.get("iou"), 3),
             _num(c.get("inside_fraction"), 3), _num(c.get("intensity_difference"), 3), _num(c.get("pose_error_m"), 3),
             _num(c.get("pose_error_deg"), 2)) for c in cams]
    a = rep.get("across", {}) or {}
    across = (f"<p>{esc(a.get('n_systems', 0))} system(s): KDE overlap of normalised scores {_num(a.get('kde_overlap_pct'), 1)} %, "
              f"Spearman rho {_num(a.get('spearman_rho'), 3)}, mean difference (photo − predicted) {_num(a.get('mean_difference'), 4)}.</p>")
    notes = "".join(f"<p class='muted'>{esc(n)}</p>" for n in a.get("notes", []) or [])
    figs = []
    first = {c.get("name") for c in cams if c.get("system") == 1}
    for fname in rep.get("figures", []) or []:
        fname = str(fname)
        is_overlay = fname.startswith("overlay.")
        if is_overlay and fname[len("overlay."):-len(".png")] not in first:
            continue
        p = folder / fname
        if not p.is_file():
            continue
        figs.append(_img(_thumbnail(read_image(p)), fname, esc(fname)))
    rel = vpath.parent.name if vpath.parent != vpath.parent.parent else str(vpath.parent)
    return (f"<h3>Simulation against photographs ({esc(rel)}/validation.json)</h3>"
            + _table(["camera", "system", "predicted px", "detected px", "IoU", "inside", "intensity diff", "pose error (m)", "pose error (deg)"], rows)
            + across + notes
            + "<p class='muted'>Predicted px: Algorithm 3 run on the render (like for like with the photograph). Overlays (system 1): "
              "target mask (yellow), prediction (green), detected outline (blue) and bounding box (red). Heatmaps: "
              "|predicted − photographed| per camera pair (thesis Figures 7.16/7.17).</p>"
            + "<div class='grid'>" + "".join(figs) + "</div>")


# --------------------------------------------------------------------------------------------------
# the page


def _load_or_run_study(run, *, samplers, ladder, time_limit_s, cache, reporter):
    from camplace.report.campaign import scoring_of
    from camplace.report.study import SamplerStudy, default_ladder, sampler_study

    path = run.outdir / "samplers.json"
    a = len(run.aims)
    lad = tuple(int(n) for n in ladder) if ladder is not None else default_ladder(run.solution.n_candidates // a, len(run.solution.cameras))
    if path.is_file():
        try:
            old = SamplerStudy.load(path)
        except CamplaceError:
            old = None
        mode = getattr(run.solution, "event_mode", "all") or "all"
        if old is not None and old.matches(run.fingerprint, run.solution.seed, len(run.solution.cameras), lad, samplers, mode, run.aims,
                                           scoring_of(run.solution)) and (
            time_limit_s is None or old.time_limit_s == float(time_limit_s)
        ):
            log.info("report: reusing %s", path)
            return old
    study = sampler_study(run, samplers=samplers, ladder=lad, time_limit_s=time_limit_s, cache=cache, reporter=reporter)
    study.save(path)
    return study


def write_report(
    outdir: str | Path,
    *,
    out: str | Path | None = None,
    union: str = "auto",
    sampler_study: bool = True,
    samplers: Sequence[str] = ("chaotic", "sobol", "uniform"),
    ladder: Sequence[int] | None = None,
    time_limit_s: float | None = None,
    cache: bool = True,
    reporter=None,
    run_data=None,
) -> Path:
    """Write ``OUTDIR/report.html`` for a run folder and every campaign folder inside it.

    Parameters
    ----------
    outdir : path
        A ``camplace run`` output folder; campaign folders (``campaign.json``) directly inside it are included.
    out : path or None
        The HTML file (default ``OUTDIR/report.html``).
    union : {"auto", "always"}
        Re-solve over the run's candidates and the campaign cameras only when a campaign system
        beats the run's (auto), or always.
    sampler_study : bool
        Include the samplers' best objective against candidates (cached in ``OUTDIR/samplers.json``).
    samplers : sequence of str
        Samplers of that study.
    ladder : sequence of int or None
        Candidate-position counts of the study (default :func:`~camplace.report.study.default_ladder`).
    time_limit_s : float or None
        Limit of each solve (study) and of the union re-solve.
    cache : bool
        Use the visibility cache.
    reporter : Reporter or None
    run_data : RunData or None
        The run folder already read (:func:`~camplace.report.compare.load_run_data`).

    Returns
    -------
    Path
        The report file.
    """
    from camplace import __version__
    from camplace._progress import Reporter
    from camplace.report.campaign import Campaign, find_campaigns
    from camplace.report.compare import compare_with_campaigns, load_run_data
    from camplace.report.figures import require_matplotlib
    from camplace.report.run_scene import SECTION_ID, scene3d_section

    require_matplotlib()
    reporter = reporter or Reporter()
    t0 = time.perf_counter()
    outdir = Path(outdir)
    run = run_data if run_data is not None else load_run_data(outdir)
    campaigns = [Campaign.load(p, matrix=True) for p in find_campaigns(outdir)]
    with reporter.stage("compare"):
        comp = compare_with_campaigns(run, campaigns, union=union, time_limit_s=time_limit_s)
    study = None
    team = getattr(run.instance, "team", None) is not None
    if team and sampler_study:
        log.warning("report: sampler study skipped: its candidate ladders are not defined for a camera team yet")
    if sampler_study and not team:
        study = _load_or_run_study(run, samplers=tuple(samplers), ladder=ladder, time_limit_s=time_limit_s, cache=cache, reporter=reporter)
    with reporter.stage("figures"):
        camp_html, _ = _campaign_section(run, comp, campaigns)
        body = [
            _instance_section(run),
            _system_section(run, comp),
            scene3d_section(run, comp, campaigns),
            _robust_section(run),
            camp_html,
            _sampler_section(run, study),
            _cones_section(run, comp, campaigns),
            _legacy_section(run, comp, campaigns),
            _validation_section(run, comp),
        ]
        from camplace.report.plan_section import plan_section  # moving agents: empty without plan.json

        body.insert(2, plan_section(run))
    sol = run.solution
    title = f"camplace report: {sol.instance or run.instance.name}"
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    nav = "".join(f"<a href='#{a}'>{t}</a>" for a, t in [("instance", "instance"), ("system", "optimised system"), (SECTION_ID, "3D view"), ("campaigns", "campaigns"),
                                                            ("samplers", "samplers"), ("cones", "vision cones"), ("legacy", "legacy score"),
                                                            ("validation", "validation")]
                  + ([("plan", "moving agents")] if (outdir / "plan.json").is_file() else []))
    page = (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        f"<meta http-equiv='Content-Security-Policy' content=\"{CSP}\">"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>{esc(title)}</title><style>{CSS}</style></head><body><main>"
        f"<h1>{esc(title)}</h1>"
        f"<p class='muted'>{esc(str(outdir))} — {len(campaigns)} campaign(s) — made {esc(stamp)} by camplace {esc(__version__)} "
        f"in {time.perf_counter() - t0:.1f} s</p><nav>{nav}</nav>"
        + "".join(body)
        + "</main></body></html>\n"
    )
    path = Path(out) if out is not None else outdir / REPORT_NAME
    write_text_atomic(path, page)
    log.info("report: wrote %s (%.1f kB) in %.2f s", path, len(page) / 1024, time.perf_counter() - t0)
    return path


def run_report_bundle(
    outdir: str | Path,
    *,
    systems: int = BUNDLE_SYSTEMS,
    campaign_samplers: Sequence[str] = BUNDLE_SAMPLERS,
    legacy_omega: float = 0.0,
    cache: bool = True,
    reporter=None,
    **report_options: Any,
) -> Path:
    """What ``camplace run ... --report`` does after the run: campaigns, then the report.

    Runs one campaign per sampler (default uniform and chaotic, 200 systems each) on the run's rows
    (its instance.toml, seed, points, event mode and k; cameras aimed like its candidates) into
    ``OUTDIR/campaign-{sampler}``, then :func:`write_report`.

    Parameters
    ----------
    outdir : path
        The run's output folder.
    systems : int
        Systems per campaign.
    campaign_samplers : sequence of str
        One campaign per sampler, into ``OUTDIR/campaign-{sampler}``.
    legacy_omega : float
        Algorithm 2's camera angle.
    cache : bool
    reporter : Reporter or None
    **report_options
        Passed to :func:`write_report`.

    Returns
    -------
    Path
        ``OUTDIR/report.html``.
    """
    from camplace.report.campaign import campaign_for_run
    from camplace.report.compare import load_run_data
    from camplace.report.figures import require_matplotlib

    require_matplotlib()
    outdir = Path(outdir)
    run = load_run_data(outdir)
    for s in campaign_samplers:
        campaign_for_run(run, systems=systems, sampler=s, legacy_omega=legacy_omega, cache=cache, reporter=reporter)
    return write_report(outdir, cache=cache, reporter=reporter, run_data=run, **report_options)
