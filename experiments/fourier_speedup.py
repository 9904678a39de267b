"""Equal-error speedup of ``fourier_filter`` over ray marching and over
``epipolar_tree``.

Mirrors Klehm et al. 2014, **§5 / Fig. 5** (quality/performance against
previous methods; "over 20x faster than the min-max-mipmap approach" on the
GPU) with the visual comparison replaced by a measured one.  The issue's
target: >= 30x over ray marching.

Per directional-light suite scene (``nave_offscreen``, ``nave_onscreen``,
``grove``, ``terrain``, ``beam``; point/spot scenes are not supported by
``fourier_filter`` and are listed as such), **640x480** (1280x960 is too
heavy here: the 2048-step exact reference of ``grove`` took 175 s at
640x480 on the shared 2 cores, ~4x that at 1280x960, and the 15-setting
sweep per scene ~4x too), 1 spp at the pixel centres:

1. ``fourier_filter`` at its defaults (rectified shadow map traced with
   Mitsuba: automatic slices, ``d`` texels per row) and with
   ``blockers=resampled`` from an orthographic ``d x d`` shadow map;
2. ``raymarch visibility=shadowmap`` with the **same shadow resolution**
   (``shadowmap_resolution = d``, the filter's texels per row, read from its
   first render) over a sweep of ``steps``;
3. ``epipolar_tree`` (defaults: traced, automatic slices) over a sweep of
   ``light_rays`` (fewer light rays: faster, less accurate);
4. relMSE (eps 1e-2, per pixel) of everything against the exact working
   reference (``raymarch visibility=exact``, 2048 steps, 1 spp at the pixel
   centres, :func:`experiments.common.exact_reference`; cached and shared
   with the ``tree_*`` experiments);
5. each baseline's time at the filter's relMSE, interpolated log-log between
   the two sweep settings that bracket it
   (:func:`experiments.tree_speedup.equal_error_time`); speedup = that time /
   the filter's time.  ``>=``: no sweep setting reaches the filter's error
   (time of the most accurate one: a lower bound); ``<=``: even the
   cheapest setting is more accurate (an upper bound).

Time conventions (medians of the warm runs, interleaved rounds in one
process, Dr.Jit on every core):

``paper``  shadow-map creation excluded (Klehm §5, Baran §10): raymarch =
    scattering minus its ``shadowmap`` stage; filter and tree = scattering
    minus their ``blockers`` stage (tracing / resampling the rectified
    blocker rows);
``scattering``  the scattering stages as they are (camera capture excluded);
``total``  end-to-end ``mi.render``.

Writes ``results/fourier_speedup/``: ``runs.csv`` (every setting),
``speedup.csv``, ``speedup.json``, ``table.md``, ``speedup.png``.
``python -m experiments.fourier_speedup [--quick] [--scenes ...] [--repeats N]``.
"""
from __future__ import annotations

import sys

import math

from . import common as c
from .fourier_table2 import STAGES, load_text, paper_time, recording_filter, timing_columns
from .tree_speedup import equal_error_time

NAME = "fourier_speedup"
SCENES = ["nave_offscreen", "nave_onscreen", "grove", "terrain", "beam", "spot_room",
          "point_fog"]
QUICK_SCENES = ["nave_offscreen"]
CONVENTIONS = {"paper": "paper_s", "scattering": "scattering_s", "total": "time_s"}
FILTERS = ("filter", "filter resampled")
BASELINES = ("raymarch", "epipolar_tree")
TARGET = 30.0


def settings_for(quick: bool) -> dict:
    """Resolution, sweeps and reference steps."""
    if quick:
        return {"width": 64, "height": 48, "steps": [4, 16, 64], "tree_light_rays": [16, 80],
                "reference_steps": 128}
    return {"width": 640, "height": 480, "steps": [8, 16, 32, 64, 128, 256, 512, 1024],
            "tree_light_rays": [50, 100, 200, 400, 800], "reference_steps": c.REFERENCE_STEPS}


def runs_of(s: dict, d: int) -> dict:
    """label -> (integrator type, properties, sweep value) with shadow
    resolution ``d``.  The tree's largest light-ray count is the image
    diagonal, its automatic count (more only in thick media)."""
    out = {"filter": ("fourier_filter", {}, None),
           "filter resampled": ("fourier_filter", {"blockers": "resampled",
                                                   "shadowmap_resolution": d}, None)}
    for n in s["steps"]:
        out[f"raymarch {n}"] = ("raymarch", {"visibility": "shadowmap", "steps": n,
                                             "shadowmap_resolution": d}, n)
    for k in s["tree_light_rays"]:
        out[f"epipolar_tree {k}"] = ("epipolar_tree", {"light_rays": k}, k)
    return out


# --------------------------------------------------------------------------
# Measuring
# --------------------------------------------------------------------------

def shadow_resolution(scene) -> tuple[int, dict]:
    """(texels per row, the whole record) of the default filter's rectified
    shadow map on this scene (one untimed render); raises if the scene is
    not supported."""
    log = []
    c.time_renders(scene, {"probe": recording_filter({}, log)}, repeats=1)
    if not log:
        raise ValueError("fourier_filter rendered no rectified shadow map on this scene")
    return log[-1]["texels"], log[-1]


def support_status(scene) -> str:
    """'ok' or the status of the default filter's failure on ``scene``."""
    res = c.time_renders(scene, {"probe": c.build("fourier_filter")}, repeats=1)
    return res["probe"].get("error", "ok")


def measure_scene(name: str, s: dict, repeats: int, progress: bool) -> list[dict]:
    """Every setting on one scene (one row each), or one row with the
    status if the filter does not support the scene."""
    path = c.scene_file(name)
    defines = c.resolution(s["width"], s["height"])
    scene = c.load(path, defines)
    status = support_status(scene)
    if status != "ok":
        return [{"scene": name, "setting": "filter", "integrator": "fourier_filter",
                 "status": status}]
    d, smap = shadow_resolution(scene)
    ref, info = c.exact_reference(path, defines, s["reference_steps"], progress=progress)
    runs = runs_of(s, d)
    logs = {k: [] for k in runs if runs[k][0] == "fourier_filter"}
    integs = {label: recording_filter(props, logs[label]) if label in logs else c.build(kind, props)
              for label, (kind, props, _) in runs.items()}
    load_before = c.load_average()
    timed = c.time_renders(scene, integs, repeats=repeats, progress=progress)
    load_after = c.load_average()
    rows = []
    for label, (kind, props, sweep) in runs.items():
        t = timed[label]
        row = {"scene": name, "setting": label, "integrator": kind, "params": props,
               "sweep": sweep, "shadow_resolution": d, "width": s["width"],
               "height": s["height"], "status": t.get("error", "ok"),
               "load_before": load_before, "load_after": load_after, "reference": info["path"]}
        if "error" not in t:
            row.update(c.errors(t["image"], ref))
            row.update(timing_columns(t))
            row["paper_s"] = paper_seconds(kind, t["stages"])
            row.update((logs.get(label) or [{}])[-1])
        rows.append(row)
    return rows


def paper_seconds(kind: str, stages: dict) -> float:
    """The ``paper`` convention (module doc) for one integrator type."""
    if kind == "raymarch":
        return stages.get("scattering", math.nan) - stages.get("shadowmap", 0.0)
    return paper_time(stages)


# --------------------------------------------------------------------------
# Equal error
# --------------------------------------------------------------------------

def baseline_curve(rows: list[dict], kind: str, key: str) -> list[tuple[float, float]]:
    """[(``key``, relMSE)] of a baseline's sweep, cheapest setting first
    (``key`` = a time column, or ``sweep`` for the steps / light rays)."""
    mine = [r for r in rows if r["integrator"] == kind and r["status"] == "ok"]
    mine.sort(key=lambda r: r["sweep"])
    return [(r[key], r["relmse_b1"]) for r in mine]


def speedups(rows: list[dict]) -> list[dict]:
    """One row per (scene, filter variant, baseline, convention)."""
    out = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        mine = [r for r in rows if r["scene"] == scene]
        for f in (r for r in mine if r["setting"] in FILTERS and r["status"] == "ok"):
            for base in BASELINES:
                for conv, key in CONVENTIONS.items():
                    t_base, bound = equal_error_time(baseline_curve(mine, base, key),
                                                     f["relmse_b1"])
                    sweep, _ = equal_error_time(baseline_curve(mine, base, "sweep"),
                                                f["relmse_b1"])
                    out.append({"scene": scene, "filter": f["setting"], "baseline": base,
                                "convention": conv, "filter_relmse_b1": f["relmse_b1"],
                                "filter_time_s": f[key], "baseline_time_s": t_base,
                                "baseline_sweep_at_equal_error": sweep, "bound": bound,
                                "speedup": t_base / f[key] if f[key] > 0 else math.nan,
                                "filter_dominant_stage": f["dominant_stage"]})
    return out


# --------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------

def speedup_table(summary: list[dict]) -> str:
    header = ["scene", "filter", "filter relMSE", "baseline", "sweep value @ equal error",
              *[f"speedup {k}" for k in CONVENTIONS]]
    body = []
    keys = dict.fromkeys((r["scene"], r["filter"], r["baseline"]) for r in summary)
    for scene, filt, base in keys:
        by = {r["convention"]: r for r in summary
              if (r["scene"], r["filter"], r["baseline"]) == (scene, filt, base)}
        p = by["paper"]
        sweep = ("" if p["bound"] == "=" else p["bound"] + " ") + \
            c.fmt(p["baseline_sweep_at_equal_error"], 4) + \
            (" steps" if base == "raymarch" else " light rays")
        body.append([scene, filt, c.fmt(p["filter_relmse_b1"]), base, sweep,
                     *(c.speedup_text(by[k]) for k in CONVENTIONS)])
    return c.markdown_table(header, body)


def runs_table(rows: list[dict]) -> str:
    header = ["scene", "setting", "paper [ms]", "scattering [ms]", "total [ms]",
              "relMSE b1", "FLIP b1", "status"]
    body = []
    for r in rows:
        ms = (lambda v: c.fmt(1000 * v, 4) if isinstance(v, float) else "-")
        body.append([r["scene"], r["setting"], ms(r.get("paper_s")), ms(r.get("scattering_s")),
                     ms(r.get("time_s")), c.fmt(r.get("relmse_b1")), c.fmt(r.get("flip_b1")),
                     "ok" if r["status"] == "ok" else r["status"][:90]])
    return c.markdown_table(header, body)


def stage_table(rows: list[dict]) -> str:
    """Where the filter's time goes: each stage in ms and % of scattering."""
    header = ["scene", "filter", "rows / texels", *STAGES, "scattering [ms]", "capture [ms]"]
    body = []
    for r in rows:
        if r["setting"] not in FILTERS or r["status"] != "ok":
            continue
        scat = 1000 * r["scattering_s"]
        body.append([r["scene"], r["setting"], f"{r.get('rows')} / {r.get('texels')}",
                     *(f"{r[f'{st}_ms']:.0f} ({100 * r[f'{st}_ms'] / scat:.0f}%)"
                       for st in STAGES),
                     f"{scat:.0f}", f"{1000 * r['stages'].get('capture', 0):.0f}"])
    return c.markdown_table(header, body)


def plot(path, rows: list[dict]) -> None:
    """Per scene: relMSE vs 'paper' time of both baselines' sweeps and the
    filters; dashed lines at the filters' errors."""
    scenes = [s for s in dict.fromkeys(r["scene"] for r in rows)
              if any(r["scene"] == s and r["status"] == "ok" for r in rows)]
    if not scenes:
        return
    fig, panels = c.scene_grid(scenes, 3, 3.3)
    for ax, scene in panels:
        ok = [r for r in rows if r["scene"] == scene and r["status"] == "ok"]
        for base, style in zip(BASELINES, ("o-", "s-")):
            pts = sorted((r for r in ok if r["integrator"] == base),
                         key=lambda r: r["sweep"])
            ax.plot([r["paper_s"] for r in pts], [r["relmse_b1"] for r in pts], style, ms=3,
                    label=base)
        for r, m in zip((r for r in ok if r["setting"] in FILTERS), "*D"):
            c.mark_at_error(ax, r, m, ms=8)
        c.style_loglog(ax, scene, "time [s] ('paper': shadow maps excluded)",
                        "relMSE vs exact")
    c.savefig(fig, path)


def report(rows, summary, s, repeats) -> str:
    loads = [r["load_before"] for r in rows if "load_before" in r]
    loads += [r["load_after"] for r in rows if "load_after" in r]
    skipped = [f"{r['scene']} ({r['status'][:60]})" for r in rows
               if r["setting"] == "filter" and r["status"] != "ok"]
    return "\n\n".join([
        f"# fourier_speedup ({s['width']}x{s['height']}, 1 spp)",
        f"Errors against the {c.reference_note(s['reference_steps'])}.  Times: median of "
        f"{repeats} warm runs, interleaved rounds, one process, "
        f"{c.environment()['drjit_threads']} threads; "
        + (load_text(loads) if loads else "no timed runs") + ".  Raymarch uses a shadow map "
        "of the filter's texels per row (column 'rows / texels').  Conventions: see the module "
        f"docstring.  Target: >= {TARGET:g}x over ray marching."
        + (f"  Not supported: {'; '.join(skipped)}." if skipped else ""),
        "## Equal-error speedup", speedup_table(summary),
        "## Where the filter's time goes (median ms, % of its scattering stage)",
        stage_table(rows),
        "## Every setting", runs_table(rows)])


def main(argv=None):
    return c.run_speedup_experiment(
        sys.modules[__name__], argv,
        {"paper": "raymarch: scattering - shadowmap; filter, tree: scattering - blockers"},
        shadow_resolution="raymarch shadowmap_resolution = the default filter's texels per "
                          "row on that scene",
        target=TARGET)


if __name__ == "__main__":
    main()
