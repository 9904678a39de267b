"""Equal-error speedup of ``epipolar_tree`` over shadow-mapped ray marching
(issue point 3).

Mirrors Baran et al. 2010, §10.1 / Fig. 11 (CPU, 1280x960, "17.1x-120.4x
for similar quality"), with the visual match replaced by a measured one:

1. on each scene, ``raymarch visibility=shadowmap`` (2048² map, 2x2 PCF)
   runs a sweep of ``steps`` (16 ... 2048); with its relMSE against the
   exact working reference (``raymarch visibility=exact``, 2048 steps, 1 spp
   at the pixel centres, :func:`experiments.common.exact_reference`) this
   gives its time/error curve;
2. ``epipolar_tree`` runs at its defaults (``traced``: light rays traced by
   Mitsuba; each sample shared by its two neighbouring slices), with half
   the automatic light rays and with slice lines up to 2 px apart (faster,
   coarser points of its own time/error curve), with each sample in its
   nearest slice only (the paper's way), and with ``blockers=resampled`` from
   a shadow map of the *same* resolution as the ray marcher's (the paper's
   setting: "both algorithms use a 4096x4096 shadow map");
3. the ray marcher's time at the tree's relMSE is interpolated log-log
   between the two sweep settings that bracket it; speedup = that time / the
   tree's time.  If even the longest run (2048 steps) does not reach the
   tree's error, the speedup is a lower bound (``>=``, the time of that
   run); if the shortest is already better, an upper bound (``<=``).
4. A second baseline, ``raymarch visibility=exact`` (32, 128, 512 steps,
   one run each): the ray marcher with the traced tree's own, ray-traced
   visibility.  The shadow-mapped marcher's relMSE has a floor set by its
   map (2048²: ~7e-6 on the nave) that the traced tree goes below, so
   against it the speedup of the traced tree is only a lower bound.
5. A third, the shadow-mapped marcher with a 4096² map (512 ... 4096
   steps, one run each), whose lower floor the tree's error may lie
   above: an equal-error time where the 2048² map gives only a bound.

Context: Baran's 17-120x are against a single-threaded scalar ray marcher
(§10.1); against a GPU ray marcher on the same GPU the paper reports 3.6x
(SIBENIK) and 4.1x (TREES) (§10.2).  Our baseline is the Dr.Jit ray
marcher: SIMD-vectorised on every core, like the paper's GPU one.

Time conventions (all medians of 3 warm runs after a warm-up, interleaved
rounds in one process, Dr.Jit on every core, OpenBLAS on one thread; the
exact ray marcher: one run; camera capture excluded from the first two):

``paper``  (Baran §10: "do not include the time taken by [the depth and
    shadow maps'] construction"): raymarch = its scattering stage minus the
    shadow-map build (the march alone); tree = its whole scattering stage
    (rectify, blockers, svd, sweep, unrectify, ring).  For ``traced`` the
    blockers stage is the tree's own visibility capture (tracing d·k rays
    per slice), kept in: conservative for the tree.  For ``resampled`` the
    blockers stage builds the same shadow map; its build time is taken out,
    estimated by the ray marcher's median ``shadowmap`` stage on that scene
    (the same ``capture_shadow_map`` call).
``scattering``: both scattering stages as they are (shadow maps included).
``total``: end-to-end ``mi.render`` (validate, capture, scattering, compose).

Writes ``results/tree_speedup/``: ``runs.csv`` (every setting: times,
stages, errors), ``speedup.csv`` (per scene, tree variant and convention),
``speedup.json``, ``table.md``, ``speedup.png``.
``python -m experiments.tree_speedup [--quick] [--scenes ...]``.
"""
from __future__ import annotations

import sys

import math

from . import common as c

NAME = "tree_speedup"
SCENES = ["nave_offscreen", "nave_onscreen", "grove", "terrain"]
QUICK_SCENES = ["nave_offscreen"]
CONVENTIONS = ("paper", "scattering", "total")
TREE_STAGES = ("rectify", "blockers", "svd", "sweep", "unrectify", "ring")
#: Baran 2010 Fig. 11 (CPU, 1280x960) and the issue's targets
PAPER_SPEEDUP = {"nave_offscreen": "~73 (SIBENIK, epipole off-screen)",
                 "nave_onscreen": "17.1 (SIBENIK)", "grove": "120.4 (TREES)",
                 "terrain": "LANDSCAPE (in 17.1-120.4)"}
TARGET = {"nave_offscreen": 50, "nave_onscreen": 50, "grove": 150}


def settings_for(quick: bool) -> dict:
    """Resolution, sweeps and shadow-map size (``--quick``: tiny)."""
    if quick:
        return {"width": 80, "height": 60, "steps": [4, 16, 64], "exact_steps": [8],
                "fine_steps": [64], "shadowmap_resolution": 256, "reference_steps": 256,
                "half_light_rays": 50}
    return {"width": 1280, "height": 960, "steps": [16, 32, 64, 128, 256, 512, 1024, 2048],
            "exact_steps": [32, 128, 512], "fine_steps": [512, 1024, 2048, 4096],
            "shadowmap_resolution": 2048, "reference_steps": c.REFERENCE_STEPS,
            "half_light_rays": 800}


def settings_of_run(s: dict) -> dict:
    """label -> (integrator type, properties) of every setting timed with
    ``repeats`` warm runs: the trees and the shadow-mapped ray marcher."""
    sm = s["shadowmap_resolution"]
    out = {"tree traced": ("epipolar_tree", {}),
           "tree traced, half light rays": ("epipolar_tree",
                                            {"light_rays": s["half_light_rays"]}),
           "tree traced, slices 2 px apart": ("epipolar_tree", {"slice_spacing": 2.0}),
           "tree traced, nearest slice (paper)": ("epipolar_tree",
                                                  {"slice_interpolation": False}),
           "tree resampled": ("epipolar_tree", {"blockers": "resampled",
                                                "shadowmap_resolution": sm})}
    return {**out, **marches("raymarch", s["steps"], visibility="shadowmap",
                             shadowmap_resolution=sm)}


def marches(label: str, steps, **props) -> dict:
    """label -> (``raymarch``, properties) at each of ``steps``."""
    return {f"{label} {n}": ("raymarch", {**props, "steps": n}) for n in steps}


def fine_settings_of_run(s: dict) -> dict:
    """The shadow-mapped ray marcher with a map of twice the resolution
    (4096²), whose error floor lies below the 2048² map's: one timed run
    each, no warm-up, like the exact marcher (seconds a run)."""
    res = 2 * s["shadowmap_resolution"]
    return marches(f"raymarch {res}²", s["fine_steps"], visibility="shadowmap",
                   shadowmap_resolution=res)


def baseline_of(props: dict, s: dict) -> str | None:
    """The ``BASELINES`` key of a ray-marcher setting (None: a tree)."""
    if props.get("visibility") == "shadowmap" and \
            props.get("shadowmap_resolution") != s["shadowmap_resolution"]:
        return FINE
    return props.get("visibility")


def exact_settings_of_run(s: dict) -> dict:
    """The ray marcher with exact (ray-traced) visibility, the same
    visibility as the traced tree: one timed run each, no warm-up (tens of
    seconds a run at 1280x960, kernel compilation < 2 % of it)."""
    return marches("raymarch exact", s["exact_steps"], visibility="exact")


# --------------------------------------------------------------------------
# Measuring
# --------------------------------------------------------------------------

def measure_scene(name: str, s: dict, repeats: int, progress: bool) -> list[dict]:
    """Every setting on one scene: times, stages and errors (one row each)."""
    scene, ref, info = c.scene_with_reference(name, s, progress)
    load_before = c.load_average()
    groups = [(settings_of_run(s), repeats, True), (exact_settings_of_run(s), 1, False),
              (fine_settings_of_run(s), 1, False)]
    rows = []
    for settings, reps, warm_up in groups:
        integs = {label: c.build(kind, props) for label, (kind, props) in settings.items()}
        timed = c.time_renders(scene, integs, repeats=reps, progress=progress,
                               contexts={label: lambda: c.limit_blas_threads(1)
                                         for label in settings},
                               warm_up=warm_up)
        for label, (kind, props) in settings.items():
            t = timed[label]
            row = {"scene": name, "setting": label, "integrator": kind, "params": props,
                   "baseline": baseline_of(props, s), "blas_threads": 1,
                   "steps": props.get("steps"), "width": s["width"], "height": s["height"],
                   "repeats": reps, "status": t.get("error", "ok"),
                   "load_before": load_before, "reference": info["path"]}
            if "error" not in t:
                row.update(c.errors(t["image"], ref))
                row.update({k: t[k] for k in ("time_s", "time_min_s", "time_max_s",
                                              "first_run_s", "scattering_s",
                                              "scattering_net_s", "stages")})
            rows.append(row)
    load_after = c.load_average()
    for row in rows:
        row["load_after"] = load_after
    add_paper_times(rows)
    return rows


def add_paper_times(rows: list[dict]) -> None:
    """``paper_s`` of every row (module doc): raymarch's march alone; the
    traced tree's scattering stage; the resampled tree's scattering stage
    minus the ray marcher's median shadow-map build on that scene."""
    builds = sorted(r["stages"]["shadowmap"] for r in rows
                    if r["status"] == "ok" and "shadowmap" in r.get("stages", {}))
    build = builds[len(builds) // 2] if builds else math.nan
    for r in rows:
        if r["status"] != "ok" or "paper_s" in r:
            continue
        if r["integrator"] == "raymarch":
            r["paper_s"] = r["scattering_net_s"]
        elif r["params"].get("blockers") == "resampled":
            r["paper_s"] = r["scattering_s"] - build
            r["shadowmap_build_estimate_s"] = build
        else:
            r["paper_s"] = r["scattering_s"]


# --------------------------------------------------------------------------
# Equal error
# --------------------------------------------------------------------------

def time_key(convention: str) -> str:
    return {"paper": "paper_s", "scattering": "scattering_s", "total": "time_s"}[convention]


def equal_error_time(curve: list[tuple[float, float]], target: float):
    """(time, bound) of the baseline at error ``target`` on ``curve`` =
    [(time, error), ...] in sweep order (more steps later).

    Log-log interpolation on the first segment whose error falls from above
    ``target`` to at or below it: bound ``"="``.  If no setting reaches
    ``target``: the last setting's time, bound ``">="`` (the speedup is at
    least time/tree).  If the first setting is already at or below it: its
    time, bound ``"<="``."""
    pts = [(t, e) for t, e in curve if t > 0 and e > 0 and math.isfinite(t * e)]
    if not pts or not (target > 0):
        return math.nan, "n/a"
    if pts[0][1] <= target:
        return pts[0][0], "<="
    for (t0, e0), (t1, e1) in zip(pts, pts[1:]):
        if e0 > target >= e1:
            w = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + w * (math.log(t1) - math.log(t0))), "="
    return pts[-1][0], ">="


#: ray-marching baselines: visibility -> what it is compared with
FINE = "shadowmap, 2x resolution"
BASELINES = {"shadowmap": "shadow map of the same resolution (the issue's comparison)",
             "exact": "ray-traced visibility, as the traced tree's blockers",
             FINE: "shadow map of twice the resolution (a lower error floor)"}


def speedups(rows: list[dict]) -> list[dict]:
    """One row per (scene, tree variant, baseline, convention): the tree's
    time and relMSE, the interpolated raymarch time and steps, speedup and
    bound."""
    out = []
    for scene in dict.fromkeys(r["scene"] for r in rows):
        mine = [r for r in rows if r["scene"] == scene and r["status"] == "ok"]
        for baseline in BASELINES:
            marches = sorted((r for r in mine if r["integrator"] == "raymarch"
                              and r["baseline"] == baseline), key=lambda r: r["steps"])
            if not marches:
                continue
            for tree in (r for r in mine if r["integrator"] == "epipolar_tree"):
                for conv in CONVENTIONS:
                    key = time_key(conv)
                    curve = [(r[key], r["relmse_b1"]) for r in marches]
                    t_rm, bound = equal_error_time(curve, tree["relmse_b1"])
                    steps, _ = equal_error_time([(r["steps"], r["relmse_b1"]) for r in marches],
                                                tree["relmse_b1"])
                    out.append({"scene": scene, "tree": tree["setting"], "baseline": baseline,
                                "convention": conv, "tree_relmse_b1": tree["relmse_b1"],
                                "tree_flip_b1": tree["flip_b1"], "tree_time_s": tree[key],
                                "raymarch_time_s": t_rm, "raymarch_steps_equal_error": steps,
                                "bound": bound,
                                "speedup": t_rm / tree[key] if tree[key] > 0 else math.nan,
                                "target": TARGET.get(scene) if baseline == "shadowmap" else None,
                                "paper": PAPER_SPEEDUP.get(scene)})
    return out


# --------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------

def speedup_table(summary: list[dict]) -> str:
    header = ["scene", "tree", "baseline (raymarch visibility)", "tree relMSE",
              "raymarch steps @ equal error", "speedup paper", "speedup scattering",
              "speedup total", "target", "paper"]
    body = []
    keys = dict.fromkeys((r["scene"], r["tree"], r["baseline"]) for r in summary)
    for (scene, tree, baseline) in keys:
        by = {r["convention"]: r for r in summary
              if (r["scene"], r["tree"], r["baseline"]) == (scene, tree, baseline)}
        p = by["paper"]
        body.append([scene, tree, baseline, c.fmt(p["tree_relmse_b1"]),
                     ("" if p["bound"] == "=" else p["bound"] + " ")
                     + c.fmt(p["raymarch_steps_equal_error"], 4),
                     *(c.speedup_text(by[k]) for k in CONVENTIONS),
                     f">= {p['target']}x" if p["target"] else "-", p["paper"] or "-"])
    return c.markdown_table(header, body)


def runs_table(rows: list[dict]) -> str:
    """Every setting: times in ms (paper / scattering / total), relMSE, FLIP."""
    header = ["scene", "setting", "paper [ms]", "scattering [ms]", "total [ms]",
              "shadow map [ms]", "relMSE b1", "FLIP b1", "relMSE b2", "status"]
    body = []
    for r in rows:
        ms = (lambda v: c.fmt(1000 * v, 4) if isinstance(v, float) else "-")
        body.append([r["scene"], r["setting"], ms(r.get("paper_s")), ms(r.get("scattering_s")),
                     ms(r.get("time_s")), ms((r.get("stages") or {}).get("shadowmap")),
                     c.fmt(r.get("relmse_b1")), c.fmt(r.get("flip_b1")),
                     c.fmt(r.get("relmse_b2")), "ok" if r["status"] == "ok" else r["status"][:80]])
    return c.markdown_table(header, body)


def stage_table(rows: list[dict]) -> str:
    """Where the tree's time goes: each stage in ms and % of scattering."""
    header = ["scene", "tree", *TREE_STAGES, "scattering [ms]", "capture [ms]", "total [ms]"]
    body = []
    for r in rows:
        if r["integrator"] != "epipolar_tree" or r["status"] != "ok":
            continue
        st, scat = r["stages"], r["scattering_s"]
        cells = [f"{1000 * st.get(k, 0):.0f} ({100 * st.get(k, 0) / scat:.0f}%)"
                 for k in TREE_STAGES]
        body.append([r["scene"], r["setting"], *cells, f"{1000 * scat:.0f}",
                     f"{1000 * st.get('capture', 0):.0f}", f"{1000 * r['time_s']:.0f}"])
    return c.markdown_table(header, body)


def plot(path, rows: list[dict]) -> None:
    """Per scene: raymarch time ('paper' convention) vs relMSE over the
    sweep, the trees as points, dashed lines at the trees' errors."""
    fig, panels = c.scene_grid(list(dict.fromkeys(r["scene"] for r in rows)), 2, 3.2)
    for ax, scene in panels:
        ok = [r for r in rows if r["scene"] == scene and r["status"] == "ok"]
        for baseline, style in zip(BASELINES, ("o-", "o:", "o--")):
            rm = sorted((r for r in ok if r["integrator"] == "raymarch"
                         and r["baseline"] == baseline), key=lambda r: r["steps"])
            ax.plot([r["paper_s"] for r in rm], [r["relmse_b1"] for r in rm], style, ms=3,
                    label=f"raymarch {baseline} (march only)")
            for r in rm:
                ax.annotate(str(r["steps"]), (r["paper_s"], r["relmse_b1"]), fontsize=6)
        for r, m in zip((r for r in ok if r["integrator"] == "epipolar_tree"), "sDv^<>"):
            c.mark_at_error(ax, r, m)
        c.style_loglog(ax, scene, "scattering time [s] ('paper' convention)",
                        "relMSE vs exact (block 1)")
    c.savefig(fig, path)


def report(rows, summary, s, repeats) -> str:
    """The markdown report (table.md)."""
    loads = [r["load_before"] for r in rows] + [r["load_after"] for r in rows]
    return "\n\n".join([
        f"# tree_speedup ({s['width']}x{s['height']}, 1 spp, shadow maps "
        f"{s['shadowmap_resolution']}²)",
        f"Errors against the {c.reference_note(s['reference_steps'])}. Times: median of "
        f"{repeats} warm runs, interleaved rounds, {c.environment()['drjit_threads']} threads; "
        f"load average (1/5/15 min) over the runs: first {loads[0]}, "
        f"max 1-min {max(l[0] for l in loads)}. Conventions: see the module docstring of "
        "experiments/tree_speedup.py ('paper' = raymarch march only vs the tree's whole "
        "scattering stage).",
        "## Equal-error speedup", speedup_table(summary),
        "## Where the tree's time goes (median ms, % of its scattering stage)",
        stage_table(rows),
        "## Every setting", runs_table(rows)])


def main(argv=None):
    return c.run_speedup_experiment(
        sys.modules[__name__], argv,
        {"paper": "raymarch: scattering minus shadow-map build; tree traced: scattering; "
                  "tree resampled: scattering minus raymarch's median shadow-map build"},
        settings=settings_of_run)


if __name__ == "__main__":
    main()
