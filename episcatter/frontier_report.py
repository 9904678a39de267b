"""Running a frontier sweep and writing what it found (DESIGN §5).

:func:`run_frontier` renders the references, runs the tasks of
:func:`episcatter.frontier.make_tasks` (locally with a progress bar, or
through any ``map_fn(fn, items)`` such as a Dask map), and writes into one
folder: ``runs.csv`` / ``runs.json`` (every run with its settings, the
sweep's settings and the environment), ``speedups.csv`` (the frontiers read
at :data:`episcatter.frontier.LEVELS`, end-to-end and scattering-only
times), ``floor.csv`` (the captures each method needs), ``capture_bound.csv`` (the
largest speedup any method could reach over the marcher, given the camera
capture), ``table.md`` and one
log-log time-vs-error plot per scene (``frontier_<scene>.png``).
"""
from __future__ import annotations

import csv
import itertools
import json
import math
import os
import statistics

import numpy as np

from . import frontier as fr

TIME_KEYS = {"time_s": "end-to-end", "scattering_s": "scattering only"}


def environment() -> dict:
    """Versions, thread counts, the machine load and the code's commit."""
    import subprocess

    import drjit as dr

    from .reference import environment as base

    env = base()
    env["drjit_threads"] = int(dr.thread_count())
    env["OPENBLAS_NUM_THREADS"] = os.environ.get("OPENBLAS_NUM_THREADS")
    env["load_average"] = [round(x, 2) for x in os.getloadavg()]
    try:
        env["git_head"] = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True,
                                         text=True, check=True,
                                         cwd=os.path.dirname(__file__)).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        env["git_head"] = None
    return env


def run_frontier(scenes, methods, budget="quick", conventions=fr.CONVENTIONS, out_dir=None,
                 defines_of=None, repeats=3, progress=True, map_fn=None, grids=None,
                 reference_spp=None) -> list[dict]:
    """Sweep ``methods`` on ``scenes`` in each convention and write the
    results into ``out_dir`` (nothing written if None).  ``defines_of(scene,
    convention)`` -> ``-D`` defines (default: none).  Returns every run row."""
    from tqdm.auto import tqdm

    if os.environ.get("OPENBLAS_NUM_THREADS") != "1":
        print("episcatter frontier: warning: OPENBLAS_NUM_THREADS is not 1; the tree's SVD "
              "timings may suffer from OpenBLAS threads (DESIGN §5)", flush=True)
    defines_of = defines_of or (lambda scene, conv: {})
    scenes = [os.path.abspath(s) for s in scenes]
    refs = {}
    settings = {"scenes": scenes, "methods": list(methods), "budget": budget,
                "conventions": list(conventions), "repeats": repeats,
                "levels": list(fr.LEVELS), "baseline": fr.BASELINE,
                "sizes": {c: defines_of(scenes[0], c) for c in conventions} if scenes else {},
                "references": refs, "reference_steps": fr.REFERENCE_STEPS,
                "antialiased_reference_spp": reference_spp or fr.ANTIALIASED_REFERENCE_SPP,
                "metric": "episcatter.metrics.scale_free_relmse (eps=1e-2)",
                "timing": "warm-up render, then the median of `repeats` interleaved "
                          "renders (dr.eval + dr.sync_thread) per setting"}
    rows = []
    for conv in conventions:          # convention-major: each finished one is a full table
        for scene in scenes:          # references first (cached), then the tasks
            path = fr.make_reference(scene, defines_of(scene, conv), conv, progress=progress,
                                     spp=reference_spp)
            refs[f"{os.path.basename(scene)}:{conv}"] = path
        tasks = fr.make_tasks(scenes, methods, budget, (conv,), defines_of,
                              {(s, conv): refs[f"{os.path.basename(s)}:{conv}"] for s in scenes},
                              repeats, grids)
        if map_fn is not None:
            rows += [r for part in map_fn(fr.run_task, tasks) for r in part]
        else:
            bar = tqdm(total=sum(len(t["settings"]) for t in tasks), desc=f"frontier {conv}",
                       unit="run", disable=not progress)
            for i, t in enumerate(tasks):
                bar.set_postfix_str(f"{os.path.basename(t['scene'])} {t['method']}")
                rows += fr.run_task(t, progress=bar.update)
                if out_dir and i + 1 < len(tasks) and tasks[i + 1]["scene"] != t["scene"]:
                    write_all(out_dir, rows, {**settings, "partial": True})   # checkpoint
            bar.close()
        if out_dir:
            write_all(out_dir, rows, {**settings, "partial": conv != conventions[-1]})
    if out_dir:
        write_all(out_dir, rows, settings)
    return rows


# --------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------

def _plain(value):
    """Strict-JSON copy of ``value``: NumPy scalars become Python numbers,
    NaN and infinities become None (``json.loads``' ``parse_constant`` sees
    exactly those bare tokens, never text inside strings)."""
    text = json.dumps(value, default=lambda o: o.item() if isinstance(o, np.generic) else str(o))
    return json.loads(text, parse_constant=lambda name: None)


def write_rows_csv(path, rows) -> None:
    """Rows as CSV; dict/list cells as JSON, NaN as empty."""
    columns = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns, restval="")
        w.writeheader()
        for r in rows:
            w.writerow({k: (json.dumps(_plain(v), sort_keys=True) if isinstance(v, (dict, list))
                            else "" if isinstance(v, float) and not math.isfinite(v) else v)
                        for k, v in r.items()})


def read_rows_csv(path) -> list[dict]:
    """The rows :func:`write_rows_csv` wrote: JSON cells (dicts, lists)
    parsed, empty cells NaN, ``True``/``False`` booleans, numbers as
    floats, the rest as text."""

    def cell(v: str):
        if v == "":
            return math.nan
        if v in ("True", "False"):
            return v == "True"
        if v[:1] in "[{":
            return json.loads(v)
        try:
            return float(v)
        except ValueError:
            return v

    with open(path, newline="") as f:
        return [{k: cell(v) for k, v in r.items()} for r in csv.DictReader(f)]


def floor_rows(rows, level: float = 1e-4) -> list[dict]:
    """Per scene x convention x method: the captures its frontier point at
    ``level`` needs (the fastest frontier setting reaching it, else the most
    accurate), its scattering time net of the visibility capture and their
    ratio (the scattering stage against the floor)."""
    out = []
    for (scene, conv, method), front in sorted(fr.fronts_by_method(rows).items()):
        if not front:
            continue
        reach = [p for p in front if p[1] <= level]
        t, e, r = reach[0] if reach else front[-1]
        cap = r.get("captures_s", math.nan)
        net = r.get("scattering_net_s", math.nan)
        out.append({"scene": scene, "convention": conv, "method": method, "level": level,
                    "reaches_level": bool(reach), "relmse": e, "time_s": t,
                    "params": r.get("params"), "spp": r.get("spp"),
                    "camera_capture_s": r.get("camera_capture_s", math.nan),
                    "visibility_capture_s": r.get("visibility_capture_s", math.nan),
                    "captures_s": cap, "scattering_net_s": net,
                    "scattering_over_captures": net / cap if cap and cap > 0 else math.nan})
    return out


def capture_bound_rows(rows, levels=fr.LEVELS) -> list[dict]:
    """Per scene x convention x level: the largest end-to-end speedup over
    ``raymarch`` that *any* method needing the camera capture could reach,
    the marcher's time at the level (:func:`episcatter.frontier.time_at_error`
    on its frontier, with its bound) over the camera capture alone (the
    G-buffer of the camera samples every method of the sweep takes; the
    median over the scene's 1-spp runs).  A method's visibility capture is
    its own choice and is not counted, so the bound is the one a free
    scattering stage would reach."""
    fronts = fr.fronts_by_method(rows)
    out = []
    for scene, conv in sorted({(r["scene"], r["convention"]) for r in rows}):
        base = fronts.get((scene, conv, fr.BASELINE))
        cams = [r.get("camera_capture_s") for r in rows
                if r["scene"] == scene and r["convention"] == conv and not r.get("error_message")
                and (r.get("spp") or 1) == 1 and isinstance(r.get("camera_capture_s"), float)
                and r["camera_capture_s"] > 0]
        if not base or not cams:
            continue
        cam = statistics.median(cams)
        for level in levels:
            t, bound = fr.time_at_error(base, level)
            out.append({"scene": scene, "convention": conv, "level": level,
                        "raymarch_time_s": t, "raymarch_bound": bound, "camera_capture_s": cam,
                        "largest_speedup": t / cam, "bound": bound})
    return out


#: the Monte Carlo ground truth, a second baseline where it was swept (end-to-end times only)
VOLPATH = "volpath"


def speedup_rows(rows) -> list[dict]:
    """:func:`episcatter.frontier.speedup_table` over the ``raymarch``
    frontier for both time keys, and over ``volpath``'s (end-to-end)."""
    return ([s for key in TIME_KEYS for s in fr.speedup_table(rows, time_key=key)]
            + fr.speedup_table(rows, baseline=VOLPATH, time_key="time_s"))


def _fmt(v, digits=3):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.{digits}g}" if isinstance(v, float) else str(v)


def markdown_report(rows, speedups, floors, bounds=()) -> str:
    """Speedup tables (one per convention, time key and baseline: method x
    scene at each level), the floor table and the capture bound of the
    speedups (:func:`capture_bound_rows`), as GitHub markdown."""
    lines = []
    scenes = sorted({r["scene"] for r in rows})
    for conv, (key, what), base in itertools.product(fr.CONVENTIONS, TIME_KEYS.items(),
                                                     (fr.BASELINE, VOLPATH)):
        sel = [s for s in speedups if s["convention"] == conv and s["time_key"] == key
               and s["baseline"] == base]
        if not sel:
            continue
        lines += [f"### Speedup over `{base}` frontier, {conv.replace('_', ' ')} "
                  f"convention, {what} time", "",
                  "| method | level | " + " | ".join(s.replace(".xml", "") for s in scenes) + " |",
                  "|---|---|" + "---|" * len(scenes)]
        for method in sorted({s["method"] for s in sel}):
            for level in fr.LEVELS:
                cells = []
                for scene in scenes:
                    hit = [s for s in sel if s["scene"] == scene and s["method"] == method
                           and s["level"] == level]
                    cells.append(fr.speedup_text(hit[0]) if hit else "-")
                lines.append(f"| {method} | {level:g} | " + " | ".join(cells) + " |")
        lines.append("")
    if floors:
        lines += ["### Captures (the floor) at the frontier point reaching relMSE 1e-4",
                  "(fastest setting reaching it, else the most accurate: `*`)", "",
                  "| scene | convention | method | relMSE | time [s] | camera capture [s] | "
                  "visibility capture [s] | scattering net [s] | net / captures |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for f in floors:
            lines.append(
                f"| {f['scene'].replace('.xml', '')} | {f['convention']} | {f['method']} | "
                f"{_fmt(f['relmse'])}{'' if f['reaches_level'] else '*'} | {_fmt(f['time_s'])} | "
                f"{_fmt(f['camera_capture_s'])} | {_fmt(f['visibility_capture_s'])} | "
                f"{_fmt(f['scattering_net_s'])} | {_fmt(f['scattering_over_captures'])} |")
    if bounds:
        lines += ["", "### The largest end-to-end speedup over `raymarch` any method could reach",
                  "(the marcher's time at the level / the camera capture every method takes: "
                  "a free scattering stage; `>=` where the marcher's sweep does not reach the "
                  "level, `<=` where its fastest setting is already below it)", "",
                  "| scene | convention | level | raymarch [s] | camera capture [s] | "
                  "largest speedup |", "|---|---|---|---|---|---|"]
        for b in bounds:
            prefix = {"=": "", ">=": ">= ", "<=": "<= "}.get(b["bound"], "? ")
            lines.append(f"| {b['scene'].replace('.xml', '')} | {b['convention']} | "
                         f"{b['level']:g} | {prefix}{_fmt(b['raymarch_time_s'])} | "
                         f"{_fmt(b['camera_capture_s'])} | "
                         f"{prefix}{_fmt(b['largest_speedup'])}x |")
    return "\n".join(lines) + "\n"


def plot_scene(path, rows, scene: str) -> None:
    """Log-log time vs relMSE of one scene, a panel per convention: every
    method's frontier as a line, its dominated settings faint, the error
    levels dotted, the reference's own noise dashed (antialiased)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    convs = [c for c in fr.CONVENTIONS if any(r["scene"] == scene and r["convention"] == c
                                             for r in rows)]
    fig, axes = plt.subplots(1, max(1, len(convs)), figsize=(5.5 * max(1, len(convs)), 4.2),
                             squeeze=False)
    fronts = fr.fronts_by_method(rows)
    for ax, conv in zip(axes[0], convs):
        sel = [r for r in rows if r["scene"] == scene and r["convention"] == conv
               and not r.get("error_message")]
        for i, method in enumerate(sorted({r["method"] for r in sel})):
            color = f"C{i}"
            pts = [(r["time_s"], r["relmse"]) for r in sel if r["method"] == method
                   and fr.usable(r["time_s"], r["relmse"])]
            front = fronts.get((scene, conv, method), [])
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o", color=color, alpha=0.2, ms=4)
            ax.plot([p[0] for p in front], [p[1] for p in front], "o-", color=color, ms=4,
                    label=method)
        for level in fr.LEVELS:
            ax.axhline(level, color="gray", ls=":", lw=0.8)
        noise = [r["reference_noise"] for r in sel if isinstance(r.get("reference_noise"), float)
                 and r["reference_noise"] > 0]
        if noise:
            ax.axhline(statistics.median(noise), color="k", ls="--", lw=0.8,
                       label="reference noise")
        size = f"{sel[0].get('width')}x{sel[0].get('height')}" if sel else ""
        ax.set(xscale="log", yscale="log", xlabel="end-to-end time [s] (median)",
               ylabel="scale-free relMSE", title=f"{scene} {size}, {conv.replace('_', ' ')}")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write_all(out_dir, rows, settings) -> None:
    """runs.csv, runs.json, speedups.csv, floor.csv, table.md and the plots."""
    os.makedirs(out_dir, exist_ok=True)
    speedups = speedup_rows(rows)
    floors = floor_rows(rows)
    bounds = capture_bound_rows(rows)
    write_rows_csv(os.path.join(out_dir, "runs.csv"), rows)
    write_rows_csv(os.path.join(out_dir, "speedups.csv"), speedups)
    write_rows_csv(os.path.join(out_dir, "floor.csv"), floors)
    write_rows_csv(os.path.join(out_dir, "capture_bound.csv"), bounds)
    with open(os.path.join(out_dir, "runs.json"), "w") as f:
        json.dump(_plain({"settings": settings, "environment": environment(), "rows": rows,
                          "speedups": speedups, "floor": floors, "capture_bound": bounds}),
                  f, indent=1)
        f.write("\n")
    with open(os.path.join(out_dir, "table.md"), "w") as f:
        f.write(markdown_report(rows, speedups, floors, bounds))
    for scene in sorted({r["scene"] for r in rows}):
        plot_scene(os.path.join(out_dir, f"frontier_{scene.replace('.xml', '')}.png"), rows, scene)
