"""Helpers shared by the experiment scripts (``python -m experiments.<name>``).

- scenes and references: :func:`scene_file`, :func:`exact_reference` (the
  working reference of DESIGN §2: ``raymarch visibility=exact``, cached by
  :func:`episcatter.reference.render_reference`);
- timing (DESIGN §5): :func:`time_renders` / :func:`time_jobs` -- one
  warm-up render per setting (compile + first run, reported apart), then
  ``repeats`` timed rounds that visit every setting once each (interleaved,
  so a change of machine load hits all settings alike), medians of the
  end-to-end time and of every stage of the render's ``RenderResult.timings``;
- errors: :func:`errors` -- :func:`episcatter.metrics.compare` at several
  block sizes, flattened into ``relmse_b1``, ``flip_b2``, ...;
- output: :func:`output_dir`, :func:`write_csv`, :func:`write_json`,
  :func:`write_text`, :func:`markdown_table`, and :func:`base_parser` for
  the common command-line options.

Every experiment writes ``results/<name>/`` with the settings that made it
and :func:`environment` (versions, threads, machine load).
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import statistics
import time
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from episcatter import bench, metrics
from episcatter.blas import blas_threads, limit_blas_threads
from episcatter.reference import environment as _base_environment
from episcatter.conventions import pixel_centre_reference
from episcatter.reference import exact_description, render_rgb, unwrap_render_error
from episcatter.scene_loading import load_scene, make_integrator

#: repository root and the folder experiments write into
ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "results"
#: ray-marching segments of the exact working reference
REFERENCE_STEPS = 2048
#: block sizes the errors are reported at (matched pixel footprint, DESIGN §2)
BLOCKS = (1, 2)


# --------------------------------------------------------------------------
# Scenes and references
# --------------------------------------------------------------------------

def scene_file(name: str) -> str:
    """Absolute path of a suite scene stem (assets built on first use) or of
    an XML file given by path."""
    import scenes

    if name in scenes.ALL_SCENES:
        return scenes.path(name)
    if os.path.isfile(name):
        return os.path.abspath(name)
    raise ValueError(f"unknown scene {name!r}: a suite stem {scenes.ALL_SCENES} or an XML path")


def resolution(width: int, height: int) -> dict:
    """The suite's ``-D`` defines for an image size."""
    return {"res_x": int(width), "res_y": int(height)}


def exact_reference(scene_path: str, defines: dict, steps: int = REFERENCE_STEPS,
                    progress: bool = True):
    """(image, info) of the exact working reference: ``raymarch
    visibility=exact steps=steps boundary_bisections=12``
    (:func:`episcatter.reference.exact_props`), one sample per pixel at the
    pixel centre.

    Rendered (or read from the cache) by :func:`render_reference` with
    ``spp=2, chunk=1``: its two halves are one non-jittered sample each, so
    they are identical (zero noise) and sample exactly where every tested
    method does at 1 spp -- the error is the integration error alone, no
    antialiasing difference (DESIGN §2)."""
    return pixel_centre_reference(scene_path, defines, int(steps), progress=progress)


def reference_note(steps: int = REFERENCE_STEPS) -> str:
    """One sentence saying what the reference and the error are (for tables
    and JSON)."""
    return (f"exact working reference: {exact_description(steps)}, "
            "1 sample per pixel at the pixel centre (same sample positions as the tested "
            "methods: pixel-centre convention); errors after block x block averaging of "
            f"both images; relMSE = {metrics.eps_text(metrics.DEFAULT_EPS)}")


# --------------------------------------------------------------------------
# Timing
# --------------------------------------------------------------------------

def load_average() -> list[float]:
    """The 1, 5 and 15 minute load averages (what ``uptime`` prints)."""
    return [round(x, 2) for x in os.getloadavg()]


def _render_once(scene, integrator, spp: int):
    """(image, wall seconds, stage timings) of one finished render."""
    t0 = time.perf_counter()
    img, stages = bench.render_with_stages(scene, integrator, spp=spp)
    seconds = time.perf_counter() - t0
    return img, seconds, stages


def summarize(first_s: float, times: list[float], stage_runs: list[dict]) -> dict:
    """Medians of the timed runs: ``time_s`` (end-to-end), ``stages``,
    ``scattering_s`` (the template's scattering stage, camera capture
    excluded), ``scattering_net_s`` (:func:`episcatter.bench.median_net_scattering`:
    it minus the visibility captures built inside it, raymarch's shadow map)."""
    stages = bench.median_stages(stage_runs)   # median of each stage in every run
    return {"first_run_s": first_s, "times_s": times, "time_s": statistics.median(times),
            "time_min_s": min(times), "time_max_s": max(times), "stages": stages,
            "scattering_s": stages.get("scattering", math.nan),
            "scattering_net_s": bench.median_net_scattering(stage_runs),
            "total_s": stages.get("total", statistics.median(times))}


def capture_substages() -> tuple[str, ...]:
    """Sub-stages of ``scattering`` that build a visibility capture which the
    papers exclude from their times (Baran §10: "do not include the time
    taken by their construction"): :data:`episcatter.bench.CAPTURE_SUBSTAGES`."""
    return bench.CAPTURE_SUBSTAGES


# --------------------------------------------------------------------------
# BLAS threads (the tree's SVD runs in NumPy): see episcatter.blas
# --------------------------------------------------------------------------

def time_renders(scene, integrators: dict, repeats: int = 3, spp: int = 1,
                 progress: bool = False, contexts: dict | None = None,
                 warm_up: bool = True) -> dict:
    """Warm-up + ``repeats`` interleaved timed renders of each integrator on
    one scene: :func:`time_jobs` with ``{label: (scene, integrator)}``."""
    return time_jobs({label: (scene, integ) for label, integ in integrators.items()},
                     repeats, spp, progress, contexts, warm_up)


def time_jobs(jobs: dict, repeats: int = 3, spp: int = 1, progress: bool = False,
              contexts: dict | None = None, warm_up: bool = True) -> dict:
    """Warm-up + ``repeats`` interleaved timed renders of each job at ``spp``
    samples per pixel (default 1: the pixel centres of the exact working
    reference; 0 = the scene's sampler, as Mitsuba does).

    ``jobs`` maps a label to ``(scene, integrator)``.  Returns, per label,
    :func:`summarize` plus ``image`` (the last render) or, if rendering
    failed, ``{"error": message}``.  Rounds are interleaved (job A, B, C, A,
    B, C, ...) so load changes on a shared machine hit every job alike.
    ``warm_up=False`` times the first render too (for runs of tens of
    seconds, where kernel compilation is negligible).
    ``contexts`` maps labels to a callable returning a context manager that
    wraps each of that job's renders (e.g. ``lambda:
    limit_blas_threads(1)``)."""
    from tqdm.auto import tqdm

    if int(repeats) < 1:
        raise ValueError(f"repeats = {repeats} must be >= 1")
    contexts = contexts or {}

    def once(label):
        scene, integrator = jobs[label]
        with contexts.get(label, nullcontext)():
            return _render_once(scene, integrator, spp)

    state = {}
    for label in jobs:
        state[label] = {"first": math.nan, "times": [], "stages": [], "image": None}
        if not warm_up:
            continue
        try:
            _, state[label]["first"], _ = once(label)
        except Exception as exc:  # noqa: BLE001 -- recorded, the others go on
            state[label] = {"error": describe_error(exc)}
    for _ in tqdm(range(int(repeats)), desc="timed rounds", disable=not progress):
        for label in [k for k in jobs if "error" not in state[k]]:
            try:
                img, seconds, stages = once(label)
            except Exception as exc:  # noqa: BLE001 -- recorded, the others go on
                state[label] = {"error": describe_error(exc)}
                continue
            s = state[label]
            s["times"].append(seconds)
            s["stages"].append(stages)
            s["image"] = img
    out = {}
    for label in jobs:
        s = state[label]
        if "error" in s:
            out[label] = {"error": s["error"]}
        else:
            out[label] = {**summarize(s["first"], s["times"], [r for r in s["stages"] if r]),
                          "image": s["image"]}
    return out


def describe_error(exc: BaseException) -> str:
    """A short status for a failed render: unsupported scenes (a
    ``ValueError`` saying so) become ``not supported yet: ...``."""
    cause = unwrap_render_error(exc)
    text = f"{type(cause).__name__}: {cause}".replace("\n", " ")
    if isinstance(cause, ValueError) and "support" in str(cause).lower():
        return "not supported yet: " + text
    return "failed: " + text


def build(kind: str, params: dict | None = None):
    """An integrator of ``kind`` with ``params`` (see ``make_integrator``)."""
    return make_integrator(kind, dict(params or {}))


def load(scene_path: str, defines: dict | None = None):
    """The scene (suite assets are built on first use)."""
    return load_scene(scene_path, defines)


# --------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------

def errors(img, ref, blocks=BLOCKS, eps: float = metrics.DEFAULT_EPS,
           eps_mode: str = metrics.DEFAULT_EPS_MODE) -> dict:
    """:func:`metrics.compare` at each block size, flattened:
    ``relmse_b<k>`` (scale-free unless ``eps_mode="absolute"``, DESIGN §2),
    ``flip_b<k>``, ``rmse_b<k>``, ``max_error_b<k>``,
    ``max_error_over_peak_b<k>``, ``mean_ratio_b<k>`` and ``nonfinite``
    (pixels with a NaN/Inf channel)."""
    out = {}
    for k in blocks:
        c = metrics.compare(img, ref, block=k, eps=eps, eps_mode=eps_mode)
        for key in ("relmse", "flip", "rmse", "max_error", "max_error_over_peak", "mean_ratio"):
            out[f"{key}_b{k}"] = c[key]
        out["nonfinite"] = c["nonfinite_test"]
    return out


# --------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------

def source_state() -> dict:
    """Which code made the numbers: the git commit and a hash of the
    working-tree sources of ``integrators/``, ``rectify/`` and
    ``episcatter/`` (uncommitted edits change it)."""
    import hashlib
    import subprocess

    h = hashlib.sha256()
    for folder in ("integrators", "rectify", "episcatter"):
        for path in sorted((ROOT / folder).glob("*.py")):
            h.update(path.name.encode())
            h.update(path.read_bytes())
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        head = None
    return {"git_head": head, "sources_sha256": h.hexdigest()[:16]}


def environment() -> dict:
    """:func:`episcatter.reference.environment` plus Dr.Jit's thread count,
    the machine load now and :func:`source_state`."""
    import drjit as dr

    env = _base_environment()
    env.update(source_state())
    env["drjit_threads"] = int(dr.thread_count())
    env["openblas_threads"] = blas_threads()
    env["load_average"] = load_average()
    return env


def output_dir(name: str, out: str | None = None, quick: bool = False) -> Path:
    """``out`` if given, else ``results/<name>`` (``results/<name>/quick``
    for ``--quick``); created."""
    path = Path(out) if out else RESULTS / name / ("quick" if quick else "")
    path.mkdir(parents=True, exist_ok=True)
    return path


def _plain(value):
    """Strict-JSON value: non-finite floats -> None, NumPy -> Python."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items() if not isinstance(v, np.ndarray)}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(path, settings: dict, rows: list[dict], **extra) -> None:
    """``{"settings", "environment", "rows", **extra}`` as strict JSON."""
    doc = {"settings": settings, "environment": environment(), "rows": rows, **extra}
    with open(path, "w") as f:
        json.dump(_plain(doc), f, indent=2)
        f.write("\n")


def _cell(value):
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.6g}"
    if isinstance(value, (dict, list, tuple)):
        return json.dumps(_plain(value), sort_keys=True)
    return value


def write_csv(path, rows: list[dict]) -> None:
    """One row per dict; columns in first-seen order; NaN is empty."""
    columns: list[str] = []
    for r in rows:
        columns += [k for k in r if k not in columns and not isinstance(r[k], np.ndarray)]
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns, restval="", extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: _cell(v) for k, v in r.items() if k in columns})


def held_out_main(doc: str, seeds, out, run, table, argv=None):
    """The command line of an experiment over held-out seeds
    (``--size WxH``, ``--seeds a,b,...``, ``--out``): ``run(seeds, width,
    height)`` -> rows, written to ``runs.csv`` (rows as they are) and
    ``table(rows, width, height)`` to ``table.md``; (rows, folder)."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--seeds", default=",".join(map(str, seeds)))
    ap.add_argument("--out", default=str(out))
    args = ap.parse_args(argv)
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    import integrators  # noqa: F401  (registers the plugins)

    width, height = (int(v) for v in args.size.split("x"))
    rows = run([int(s) for s in args.seeds.split(",")], width, height)
    folder = Path(args.out)
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "runs.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (folder / "table.md").write_text(table(rows, width, height))
    return rows, folder


def write_text(path, text: str) -> None:
    with open(path, "w") as f:
        f.write(text.rstrip() + "\n")


def fmt(value, digits: int = 3) -> str:
    """Compact number for tables ('-' for missing / NaN)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{value:.{digits}g}"
    return str(value)


def markdown_table(header: list[str], rows: list[list]) -> str:
    """A GitHub markdown table of already formatted cells."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def base_parser(doc: str, default_scenes: list[str], quick_scenes: list[str]):
    """Options every experiment takes: ``--quick``, ``--scenes``,
    ``--repeats``, ``--out``; the scene defaults depend on ``--quick``
    (resolve with :func:`scenes_of`)."""
    p = argparse.ArgumentParser(description=doc.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true",
                   help="tiny resolution and few settings (seconds; used by the tests)")
    p.add_argument("--scenes", nargs="+", default=None,
                   help=f"scene stems or XML paths (default {' '.join(default_scenes)}; "
                        f"--quick: {' '.join(quick_scenes)})")
    p.add_argument("--repeats", type=int, default=None,
                   help="timed runs per setting after the warm-up (default 3, --quick 1)")
    p.add_argument("--out", default=None, help="output folder (default results/<name>)")
    p.add_argument("--resume", action="store_true",
                   help="reuse the per-scene checkpoints a previous run left in "
                        "<out>/checkpoints/ (same settings) instead of measuring again")
    p.add_argument("--size", default=None, metavar="WxH",
                   help="image size, instead of the experiment's own (e.g. 1280x960)")
    p.set_defaults(_scenes=(default_scenes, quick_scenes))
    return p


def sized(settings: dict, size: str | None) -> dict:
    """``settings`` with ``width``/``height`` taken from a ``--size`` WxH
    (unchanged when ``size`` is None)."""
    if size is None:
        return settings
    if "width" not in settings or "height" not in settings:
        raise ValueError("--size: this experiment has no single image size to replace "
                         "(its settings have no width/height); drop --size")
    try:
        w, h = (int(v) for v in str(size).lower().split("x"))
    except ValueError:
        raise ValueError(f"--size {size!r}: give WIDTHxHEIGHT, e.g. 1280x960") from None
    if w < 1 or h < 1:
        raise ValueError(f"--size {size!r}: width and height must be >= 1")
    return {**settings, "width": w, "height": h}


def scenes_of(args) -> list[str]:
    """The scenes an experiment runs on (``--scenes`` or the defaults)."""
    default, quick = args._scenes
    return args.scenes or (quick if args.quick else default)


def repeats_of(args) -> int:
    """Timed runs per setting: ``--repeats`` or 3 (1 with ``--quick``)."""
    return args.repeats or (1 if args.quick else 3)


def savefig(fig, path) -> None:
    """Save a small PNG and close the figure."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def pyplot():
    """matplotlib.pyplot with the Agg backend."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


__all__ = ["ROOT", "RESULTS", "REFERENCE_STEPS", "BLOCKS", "scene_file", "resolution",
           "exact_reference", "reference_note", "load_average", "summarize",
           "capture_substages", "source_state", "blas_threads", "limit_blas_threads", "time_renders", "time_jobs", "describe_error", "build", "load", "errors",
           "environment", "output_dir", "write_json", "write_csv", "write_text", "fmt",
           "markdown_table", "base_parser", "scenes_of", "repeats_of", "savefig", "pyplot"]


@dataclass
class Run:
    """What an experiment's ``main`` starts from (:func:`start_run`)."""
    args: argparse.Namespace
    settings: dict
    repeats: int
    out: Path
    scenes: list


def start_run(module, argv, default_scenes: list, quick_scenes: list,
              default_repeats: int = 3) -> Run:
    """Parse the common options of experiment ``module`` (its ``__doc__``,
    ``NAME``, ``settings_for``): settings, repeats (``--repeats``, else
    ``default_repeats``, 1 with ``--quick``), output folder, scenes."""
    args = base_parser(module.__doc__, default_scenes, quick_scenes).parse_args(argv)
    repeats = args.repeats or (1 if args.quick else default_repeats)
    return Run(args, sized(module.settings_for(args.quick), args.size), repeats,
               output_dir(module.NAME, args.out, args.quick), scenes_of(args))


def scene_rows_checkpointed(folder: Path, name: str, settings: dict, resume: bool,
                            measure) -> list[dict]:
    """``measure()``'s rows for scene ``name``, saved to ``folder/<stem>.pkl``
    with the settings they were measured with; with ``resume`` a saved file
    of the same settings is returned instead of measuring again (a long
    experiment interrupted after some scenes restarts where it stopped)."""
    import pickle
    path = Path(folder) / f"{Path(str(name)).stem}.pkl"
    if resume and path.exists():
        with open(path, "rb") as f:
            saved = pickle.load(f)
        if saved.get("settings") == _plain(settings):
            print(f"{name}: rows from {path}", flush=True)
            return saved["rows"]
        print(f"{name}: {path} has other settings; measuring again", flush=True)
    rows = measure()
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        pickle.dump({"settings": _plain(settings), "rows": rows}, f)
    return rows


def measured_scenes(module, argv) -> tuple[Run, list[dict]]:
    """(run, rows): the common arguments parsed (:func:`start_run`) and
    ``module.measure_scene(name, settings, repeats, progress)``'s rows of
    every scene, checkpointed per scene (:func:`scene_rows_checkpointed`)."""
    run = start_run(module, argv, module.SCENES, module.QUICK_SCENES)
    s, repeats = run.settings, run.repeats
    rows = []
    for name in run.scenes:
        rows += scene_rows_checkpointed(
            run.out / "checkpoints", name, {**s, "repeats": repeats}, run.args.resume,
            lambda: module.measure_scene(name, s, repeats, progress=not run.args.quick))
        print(f"{name}: done (load {load_average()})", flush=True)
    return run, rows


def run_speedup_experiment(module, argv, conventions: dict, **extra_settings):
    """The driver both equal-error speedup experiments share: parse the
    common arguments, run ``module.measure_scene`` on every scene, summarise
    with ``module.speedups``, and write runs.csv, speedup.csv, speedup.json,
    table.md (``module.report``) and speedup.png (``module.plot``) under
    ``results/<module.NAME>/``.  Returns (rows, summary)."""
    run, rows = measured_scenes(module, argv)
    args, s, repeats, out = run.args, run.settings, run.repeats, run.out
    summary = module.speedups(rows)
    text = module.report(rows, summary, s, repeats)
    print(text)
    settings = {"name": module.NAME, **s, "repeats": repeats, "scenes": run.scenes,
                "reference": reference_note(s["reference_steps"]),
                "conventions": {**conventions,
                                "scattering": "RenderResult.timings['scattering'] (median)",
                                "total": "end-to-end mi.render wall time (median)"},
                "quick": args.quick, **{k: (v(s) if callable(v) else v)
                                        for k, v in extra_settings.items()}}
    write_csv(out / "runs.csv", rows)
    write_csv(out / "speedup.csv", summary)
    write_json(out / "speedup.json", settings, rows, speedup=summary)
    write_text(out / "table.md", text)
    module.plot(out / "speedup.png", rows)
    return rows, summary


def run_table_experiment(module, argv) -> list[dict]:
    """The driver of an experiment with one table over scenes: parse the
    common arguments, run ``module.measure_scene(name, settings, repeats,
    progress)`` on every scene (checkpointed per scene), print and write
    ``module.report(rows, settings, repeats)`` as ``table.md`` and the rows
    as ``runs.csv`` and ``runs.json`` (with the settings, environment and
    source state) under ``results/<module.NAME>/``.  Returns the rows."""
    run, rows = measured_scenes(module, argv)
    args, s, repeats, out = run.args, run.settings, run.repeats, run.out
    text = module.report(rows, s, repeats)
    print(text)
    settings = {"name": module.NAME, **s, "repeats": repeats, "scenes": run.scenes,
                "quick": args.quick, "environment": environment(), "source": source_state()}
    if "reference_steps" in s:
        settings["reference"] = reference_note(s["reference_steps"])
    write_csv(out / "runs.csv", rows)
    write_json(out / "runs.json", settings, rows)
    write_text(out / "table.md", text)
    return rows


def scene_with_reference(name: str, s: dict, progress: bool, **defines):
    """(scene, exact reference image, its info) of suite scene ``name`` at
    ``s['width']``×``s['height']`` (plus ``defines``), the reference made
    with ``s['reference_steps']`` (cached)."""
    path = scene_file(name)
    defines = {**resolution(s["width"], s["height"]), **defines}
    ref, info = exact_reference(path, defines, s["reference_steps"], progress=progress)
    return load(path, defines), ref, info


def timed_scattering(name: str, s: dict, settings: dict, repeats: int, progress: bool):
    """(reference, timed): suite scene ``name`` with its exact reference
    (:func:`scene_with_reference`) and :func:`time_renders` of every
    ``{label: (integrator type, properties)}`` of ``settings``, output
    ``scattering``, one sample per pixel."""
    scene, ref, _ = scene_with_reference(name, s, progress)
    integs = {label: build(kind, {"output": "scattering", **props})
              for label, (kind, props) in settings.items()}
    return ref, time_renders(scene, integs, repeats, spp=1, progress=progress)


def speedup_text(r: dict) -> str:
    """``r['speedup']`` with its bound (``>=``/``<=``; ``?`` if unknown)."""
    prefix = {"=": "", ">=": ">= ", "<=": "<= "}.get(r["bound"], "? ")
    return prefix + fmt(r["speedup"]) + "x"


def scene_grid(scenes: list, cols: int, height: float):
    """(figure, [(axes, scene), ...]): one log-log panel per scene, ``cols``
    per row; unused panels switched off."""
    plt = pyplot()
    cols = min(cols, len(scenes))
    nrows = math.ceil(len(scenes) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, height * nrows), squeeze=False)
    for ax in list(axes.flat)[len(scenes):]:
        ax.axis("off")
    return fig, list(zip(axes.flat, scenes))


def mark_at_error(ax, r: dict, marker: str, **kw) -> None:
    """A method's (paper time, relMSE) point and a dashed line at its error."""
    ax.plot([r["paper_s"]], [r["relmse_b1"]], marker, label=r["setting"], **kw)
    ax.axhline(r["relmse_b1"], ls="--", lw=0.6, color="gray")


def style_loglog(ax, title: str, xlabel: str, ylabel: str) -> None:
    """The log-log time/error axes every experiment plot uses."""
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel(xlabel, fontsize=8)
    ax.set_ylabel(ylabel, fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6)
