"""Is ``fourier_filter``'s cost independent of the scene?

Mirrors Klehm et al. 2014, **§5** ("it is independent of the scene
complexity and configuration ... Our cost is O(wh + ad) ... Our method
shows constant performance"; Fig. 5/6, Table 2's constant "Scattering"
column).  Target of the issue: max/min scattering time over the
directional-light suite <= 1.3x.

Every suite scene at 1280x960, 1 spp at the pixel centres, two settings:

``fixed``  ``slices=1024, light_rays=1024`` (the paper's condition: one
           rectified shadow-map size for every scene; Table 2's 1024x1024)
``auto``   the integrator's defaults (slices from Baran's sinh
           distribution, which depends on where the epipole is; light rays
           from the image diagonal, more in thick media)

Point and spot scenes (``spot_room``, ``point_fog``) are not supported by
``fourier_filter`` yet: they are listed with that status, not timed.

Times (all scenes and settings loaded in one process, warmed up once, then
``repeats`` interleaved rounds over every (scene, setting) so a change of
machine load hits all alike; medians): ``scattering`` = the template's
scattering stage (camera capture excluded), ``paper`` = it minus the
``blockers`` stage (tracing the rectified shadow map; Klehm §5 excludes
shadow-map creation), ``total`` = end-to-end ``mi.render``; plus every
stage.  The machine is shared and its load comes in bursts that even
interleaving does not fully cancel, so the fastest run of each
(``scattering (min)``, ``paper (min)``) and the median process CPU time of a
whole render (``total CPU``: all Dr.Jit threads' work, insensitive to
waiting for a core) are given next to the medians.  The summary gives
max/min over the supported scenes for each of these and for each stage
(median).  Errors are not measured here (no 1280x960
references; see ``fourier_speedup`` at 640x480).

Writes ``results/fourier_scene_independence/``: ``scenes.csv``,
``ratios.csv``, ``scenes.json``, ``table.md``, ``scenes.png``.
``python -m experiments.fourier_scene_independence [--quick] [--scenes ...]``.
"""
from __future__ import annotations

import sys

import statistics
import time

from episcatter import bench

from . import common as c
from .fourier_table2 import STAGES, load_text, paper_time, recording_filter, timing_columns

NAME = "fourier_scene_independence"
SUITE = ["nave_offscreen", "nave_onscreen", "grove", "terrain", "spot_room", "point_fog", "beam"]
QUICK_SCENES = ["nave_offscreen", "beam", "point_fog"]
TARGET_RATIO = 1.3
#: quantity -> column: medians (DESIGN §5), minima over the runs (robust to
#: bursts of load from other jobs), and the process CPU time of a render
CONVENTIONS = {"scattering": "scattering_s", "paper": "paper_s", "total": "time_s",
               "scattering (min)": "scattering_min_s", "paper (min)": "paper_min_s",
               "total CPU": "cpu_s"}


def settings_for(quick: bool) -> dict:
    """Resolution and the two fourier_filter settings."""
    if quick:
        return {"width": 64, "height": 48,
                "settings": {"fixed": {"slices": 64, "light_rays": 64}, "auto": {}}}
    return {"width": 1280, "height": 960,
            "settings": {"fixed": {"slices": 1024, "light_rays": 1024}, "auto": {}}}


# --------------------------------------------------------------------------
# Interleaved timing over scenes
# --------------------------------------------------------------------------

def timed_render(scene, integrator, log: list) -> tuple:
    """(image, wall seconds, stage timings, process CPU seconds) of one
    render of a :func:`~experiments.fourier_table2.recording_filter`, its
    rectified shadow map appended to ``log``."""
    integrator.map_log = log
    t0, cpu0 = time.perf_counter(), time.process_time()
    img, stages = bench.render_with_stages(scene, integrator, spp=1)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    return img, seconds, stages, cpu


def warm_up(jobs: dict) -> dict:
    """One render of every job: state per key, or ``{"error": status}``."""
    state = {}
    for key, (scene, integ) in jobs.items():
        log = []
        try:
            _, first, _, _ = timed_render(scene, integ, log)
            state[key] = {"first": first, "times": [], "stages": [], "cpu": [], "log": log}
        except Exception as exc:  # noqa: BLE001 -- recorded (unsupported scenes)
            state[key] = {"error": c.describe_error(exc)}
    return state


def interleaved_times(jobs: dict, repeats: int, progress: bool) -> dict:
    """Warm-up, then ``repeats`` rounds visiting every (scene, setting) once;
    per key :func:`experiments.common.summarize` plus :func:`minima`, the
    median CPU time ``cpu_s`` and the shadow-map log, or ``{"error": ...}``."""
    from tqdm.auto import tqdm

    state = warm_up(jobs)
    live = [k for k in jobs if "error" not in state[k]]
    for _ in tqdm(range(int(repeats)), desc="rounds", disable=not progress):
        for key in live:
            scene, integ = jobs[key]
            _, seconds, stages, cpu = timed_render(scene, integ, state[key]["log"])
            state[key]["times"].append(seconds)
            state[key]["stages"].append(stages)
            state[key]["cpu"].append(cpu)
    out = {}
    for key, s in state.items():
        if "error" in s:
            out[key] = s
            continue
        out[key] = {**c.summarize(s["first"], s["times"], s["stages"]), **minima(s["stages"]),
                    "cpu_s": statistics.median(s["cpu"]), "cpu_runs_s": s["cpu"],
                    "log": s["log"]}
    return out


def minima(stage_runs: list[dict]) -> dict:
    """The fastest run's scattering stage and 'paper' time, and the minimum
    of every stage (``stages_min``)."""
    names = set.intersection(*(set(r) for r in stage_runs))
    return {"stages_min": {k: min(r[k] for r in stage_runs) for k in sorted(names)},
            "scattering_min_s": min(r["scattering"] for r in stage_runs),
            "paper_min_s": min(paper_time(r) for r in stage_runs)}


# --------------------------------------------------------------------------
# Measuring
# --------------------------------------------------------------------------

def measure(scene_names: list[str], s: dict, repeats: int, progress: bool) -> list[dict]:
    """One row per (scene, setting)."""
    defines = c.resolution(s["width"], s["height"])
    jobs = {}
    for name in scene_names:
        scene = c.load(c.scene_file(name), defines)
        for label, props in s["settings"].items():
            jobs[(name, label)] = (scene, recording_filter(props, []))
    load_before = c.load_average()
    timed = interleaved_times(jobs, repeats, progress)
    load_after = c.load_average()
    rows = []
    for (name, label), t in timed.items():
        row = {"scene": name, "setting": label, "params": s["settings"][label],
               "width": s["width"], "height": s["height"], "status": t.get("error", "ok"),
               "load_before": load_before, "load_after": load_after}
        if "error" not in t:
            row.update(timing_columns(t))
            row.update({k: t[k] for k in ("scattering_min_s", "paper_min_s", "cpu_s",
                                          "cpu_runs_s", "stages_min")})
            row.update(t["log"][-1] if t["log"] else {})
        rows.append(row)
    return rows


#: stages shorter than this in some scene get no ratio (e.g. ``ring``, which
#: is empty unless the epipole is on screen: its ratio means nothing)
MIN_STAGE_MS = 1.0


def ratios(rows: list[dict]) -> list[dict]:
    """max/min over the supported scenes per setting, for each time
    convention and each stage (stages under ``MIN_STAGE_MS`` in some scene
    are left out), with the scenes at the extremes."""
    out = []
    for label in dict.fromkeys(r["setting"] for r in rows):
        ok = [r for r in rows if r["setting"] == label and r["status"] == "ok"]
        if len(ok) < 2:
            continue
        keys = dict(CONVENTIONS, **{st: f"{st}_ms" for st in STAGES})
        for what, key in keys.items():
            if any(key not in r for r in ok):
                continue
            vals = [(r[key], r["scene"]) for r in ok]
            if what not in CONVENTIONS and min(v for v, _ in vals) < MIN_STAGE_MS:
                continue
            hi, lo = max(vals), min(vals)
            out.append({"setting": label, "quantity": what, "max": hi[0], "max_scene": hi[1],
                        "min": lo[0], "min_scene": lo[1], "ratio": hi[0] / lo[0],
                        "median": statistics.median(v for v, _ in vals),
                        "meets_target": (hi[0] / lo[0] <= TARGET_RATIO)
                        if what in CONVENTIONS else None})
    return out


# --------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------

def scene_table(rows: list[dict]) -> str:
    header = ["scene", "setting", "rows / texels (filtered rows)", "scattering [ms]",
              "paper [ms]", "total [ms]", *[f"{st} [ms]" for st in STAGES], "status"]
    body = []
    for r in rows:
        if r["status"] != "ok":
            body.append([r["scene"], r["setting"], *["-"] * (4 + len(STAGES)), r["status"][:90]])
            continue
        body.append([r["scene"], r["setting"],
                     f"{r.get('rows')} / {r.get('texels')} ({r.get('filtered_rows')})",
                     c.fmt(1000 * r["scattering_s"]), c.fmt(1000 * r["paper_s"]),
                     c.fmt(1000 * r["time_s"]), *[c.fmt(r[f"{st}_ms"]) for st in STAGES], "ok"])
    return c.markdown_table(header, body)


def ratio_table(summary: list[dict]) -> str:
    header = ["setting", "quantity", "max/min", "max (scene)", "min (scene)",
              f"<= {TARGET_RATIO}x?"]
    unit = (lambda q: 1000 if q in CONVENTIONS else 1)
    body = [[r["setting"], r["quantity"], f"{r['ratio']:.2f}x",
             f"{c.fmt(r['max'] * unit(r['quantity']))} ms ({r['max_scene']})",
             f"{c.fmt(r['min'] * unit(r['quantity']))} ms ({r['min_scene']})",
             {True: "yes", False: "no", None: ""}[r["meets_target"]]] for r in summary]
    return c.markdown_table(header, body)


def plot(path, rows: list[dict]) -> None:
    """Stacked stage times per scene, one group per setting."""
    plt = c.pyplot()
    ok = [r for r in rows if r["status"] == "ok"]
    labels = [f"{r['scene']}\n{r['setting']}" for r in ok]
    fig, ax = plt.subplots(figsize=(max(5.0, 0.75 * len(ok) + 2), 4))
    bottom = [0.0] * len(ok)
    for st in STAGES:
        vals = [r[f"{st}_ms"] for r in ok]
        ax.bar(range(len(ok)), vals, bottom=bottom, label=st)
        bottom = [b + v for b, v in zip(bottom, vals)]
    ax.set_xticks(range(len(ok)), labels, rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("median stage time [ms]")
    ax.set_title("fourier_filter scattering stages per scene", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    c.savefig(fig, path)


def report(rows, summary, s, repeats) -> str:
    loads = [r["load_before"] for r in rows] + [r["load_after"] for r in rows]
    return "\n\n".join([
        f"# fourier_scene_independence ({s['width']}x{s['height']}, 1 spp)",
        f"Median of {repeats} warm runs, all (scene, setting) pairs interleaved in one process, "
        f"{c.environment()['drjit_threads']} threads; {load_text(loads)}.  'paper' = "
        "scattering minus the rectified shadow-map build (blockers); '(min)' = the fastest run "
        "instead of the median; 'total CPU' = median process CPU time of a whole render "
        "(camera capture included).  Target: max/min <= "
        f"{TARGET_RATIO}x over the supported scenes.",
        "## max/min over scenes", ratio_table(summary),
        "## Per scene (median ms)", scene_table(rows)])


def main(argv=None):
    run = c.start_run(sys.modules[__name__], argv, SUITE, QUICK_SCENES)
    args, s, repeats, out = run.args, run.settings, run.repeats, run.out
    rows = measure(run.scenes, s, repeats, progress=not args.quick)
    summary = ratios(rows)
    text = report(rows, summary, s, repeats)
    print(text)
    settings = {"name": NAME, **s, "repeats": repeats, "scenes": run.scenes,
                "target_ratio": TARGET_RATIO,
                "conventions": {"scattering": "RenderResult.timings['scattering'] (median)",
                                "paper": "scattering minus the 'blockers' stage",
                                "total": "end-to-end mi.render wall time (median)"},
                "quick": args.quick}
    c.write_csv(out / "scenes.csv", rows)
    c.write_csv(out / "ratios.csv", summary)
    c.write_json(out / "scenes.json", settings, rows, ratios=summary)
    c.write_text(out / "table.md", text)
    plot(out / "scenes.png", rows)
    return rows, summary


if __name__ == "__main__":
    main()
