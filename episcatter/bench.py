"""Time-and-error benchmarks of integrators (DESIGN §5).

:func:`bench_job` is one measurement and takes only file paths and plain
values, so it can be shipped to another process or a Dask worker as is.
:func:`run_bench` expands sweeps into jobs, runs them, and writes
``bench.csv``, ``bench.json`` and ``bench.png`` into one output folder.

How times are measured: the scene is loaded and the integrator built (not
timed as rendering: ``load_s``); one warm-up render is timed as
``first_run_s`` (kernel compilation + first run; Dr.Jit may take kernels
from its disk cache, so this is an upper bound on the run time, not a pure
compile time); then ``repeats`` renders through ``mi.render`` with
``dr.eval`` + ``dr.sync_thread`` before the clock stops.  ``time_s`` is the
median end-to-end wall time of those; for episcatter integrators the median
of each stage in ``integrator.timings`` is also reported (``stage_<name>_s``,
``scattering_s`` = the scattering stage alone, camera capture excluded, the
papers' convention; ``scattering_net_s`` also excludes the method's own
sub-stages, e.g. building the shadow map).  Plain Mitsuba integrators (e.g. ``volpath``) only have
the end-to-end time.

Parameters: ``params`` are integrator properties, except ``spp``, which is
passed to ``mi.render`` (0 or absent: the integrator's / scene's own count).
A name ``TYPE.name`` applies only to integrator ``TYPE`` (``raymarch.steps``),
a bare name to every integrator, so one sweep can mix methods whose
properties differ.

Errors are measured with :func:`episcatter.metrics.compare` against a
reference EXR (its ``full`` layer), after averaging both images over
``block`` x ``block`` pixel blocks (matched pixel footprint, DESIGN §2).
"""
from __future__ import annotations

import csv
import datetime
import itertools
import json
import math
import os
import statistics
import time

import numpy as np

from . import metrics
from .reference import environment, load_halves, load_reference, render_reference, render_rgb

SPP_PARAM = "spp"
#: stages of the render template; any other stage in integrator.timings is a
#: method's sub-stage of "scattering" (e.g. raymarch's "shadowmap").
TEMPLATE_STAGES = ("validate", "capture", "scattering", "compose", "total")
METRIC_KEYS = ("relmse", "rmse", "mape", "max_error", "mean_ratio", "flip")
BASE_COLUMNS = (
    "scene", "integrator", "params", "spp", "width", "height", "repeats",
    "load_s", "first_run_s", "time_s", "time_min_s", "time_max_s", "scattering_s", "scattering_net_s",
)
TAIL_COLUMNS = METRIC_KEYS + ("block", "eps", "reference", "reference_kind",
                              "reference_spp", "reference_noise", "error")


# --------------------------------------------------------------------------
# One job
# --------------------------------------------------------------------------

def params_for(integrator_type: str, params: dict | None) -> dict:
    """The parameters that apply to ``integrator_type``: bare names, and
    ``TYPE.name`` entries of this type with the prefix removed (they win)."""
    out, scoped = {}, {}
    for key, value in (params or {}).items():
        prefix, dot, name = key.rpartition(".")
        if not dot:
            out[key] = value
        elif prefix == integrator_type:
            scoped[name] = value
    out.update(scoped)
    return out


def _timed_render(scene, integrator, spp, seed=0):
    """(image, wall seconds, integrator stage timings or {})."""
    t0 = time.perf_counter()
    img = render_rgb(scene, integrator, spp=spp, seed=seed)
    seconds = time.perf_counter() - t0
    return img, seconds, dict(getattr(integrator, "timings", None) or {})


def _median_stages(stage_runs: list[dict]) -> dict:
    """Median of each stage present in every run."""
    if not stage_runs:
        return {}
    names = set.intersection(*(set(r) for r in stage_runs))
    return {k: statistics.median(r[k] for r in stage_runs) for k in sorted(names)}


def _errors(img, reference_path, block, eps) -> dict:
    """Metrics of ``img`` against the reference (empty if none)."""
    if not reference_path:
        return {}
    ref, info = load_reference(reference_path)
    result = metrics.compare(img, ref, block=block, eps=eps)
    try:
        noise = metrics.noise_relmse(*load_halves(reference_path), block=block, eps=eps)
    except KeyError:  # an EXR without the two halves
        noise = math.nan
    result.update(reference=os.path.abspath(reference_path),
                  reference_kind=info.get("kind"), reference_spp=info.get("spp"),
                  reference_noise=noise)
    return result


def bench_job(scene_path: str, integrator_type: str, params: dict | None = None,
              defines: dict | None = None, reference_path: str | None = None,
              repeats: int = 3, block: int = 1, eps: float = metrics.DEFAULT_EPS,
              seed: int = 0) -> dict:
    """Time one integrator setting on one scene and measure its error.

    Returns a flat dict: the inputs, ``width``/``height``, ``load_s``,
    ``first_run_s`` (warm-up: compile + first run), ``times_s`` (each timed
    run), ``time_s`` (their median), ``time_min_s``, ``time_max_s``,
    ``stages`` (median seconds per stage of ``integrator.timings``, empty for
    plain Mitsuba integrators), ``scattering_s`` (the scattering stage, NaN
    without stages), ``scattering_net_s`` (it minus the method's own
    sub-stages such as a shadow-map build), and,
    with a reference, the keys of :func:`metrics.compare` plus
    ``reference``, ``reference_kind``, ``reference_spp`` and
    ``reference_noise`` (the reference's own relMSE noise at this block and
    eps, from its two halves: errors below it are not resolved).
    Every run uses the same ``seed``; the error is that of the last run.
    """
    from .scene_loading import load_scene, make_integrator

    if int(repeats) < 1:
        raise ValueError(f"repeats = {repeats} must be >= 1.")
    props = params_for(integrator_type, params)
    spp = int(props.pop(SPP_PARAM, 0) or 0)
    t0 = time.perf_counter()
    scene = load_scene(scene_path, defines)
    integrator = make_integrator(integrator_type, props, scene)
    load_s = time.perf_counter() - t0

    _, first_s, _ = _timed_render(scene, integrator, spp, seed)
    img, times, stage_runs = None, [], []
    for _ in range(int(repeats)):
        img, seconds, stages = _timed_render(scene, integrator, spp, seed)
        times.append(seconds)
        if stages:
            stage_runs.append(stages)
    stages = _median_stages(stage_runs)
    sub = sum(v for k, v in stages.items() if k not in TEMPLATE_STAGES)
    result = {
        "scene": os.path.abspath(scene_path), "integrator": integrator_type,
        "params": props, "spp": spp, "defines": {k: str(v) for k, v in (defines or {}).items()},
        "width": int(img.shape[1]), "height": int(img.shape[0]),
        "repeats": int(repeats), "seed": int(seed), "load_s": load_s,
        "first_run_s": first_s, "times_s": times, "time_s": statistics.median(times),
        "time_min_s": min(times), "time_max_s": max(times),
        "stages": stages, "scattering_s": stages.get("scattering", math.nan),
        "scattering_net_s": stages.get("scattering", math.nan) - sub,
        "block": int(block), "eps": float(eps),
    }
    if reference_path and props.get("output", "full") != "full":
        result["error"] = (f"output={props['output']} is not comparable with the "
                           "reference's full image; metrics skipped")
        return result
    result.update(_errors(img, reference_path, block, eps))
    return result


# --------------------------------------------------------------------------
# Sweeps
# --------------------------------------------------------------------------

def expand_jobs(scenes, integrators, params=None, sweeps=None) -> list[dict]:
    """One job description (scene, integrator, params) per scene x integrator
    x combination of the sweep values that apply to that integrator."""
    _check_scopes(integrators, params, sweeps)
    jobs = []
    for scene in scenes:
        for kind in integrators:
            axes = [(name, values) for name, values in (sweeps or {}).items()
                    if "." not in name or name.rpartition(".")[0] == kind]
            names = [name for name, _ in axes]
            for combo in itertools.product(*(values for _, values in axes)):
                p = dict(params or {})
                p.update(zip(names, combo))
                jobs.append({"scene": scene, "integrator": kind,
                             "params": params_for(kind, p)})
    return jobs


def _check_scopes(integrators, params, sweeps) -> None:
    """Refuse ``TYPE.name`` parameters whose TYPE is not benchmarked (typos)."""
    for name in list(params or {}) + list(sweeps or {}):
        prefix = name.rpartition(".")[0]
        if prefix and prefix not in integrators:
            raise ValueError(f"Parameter '{name}' is scoped to integrator '{prefix}', "
                             f"which is not among the benchmarked ones {list(integrators)}.")


def make_references(scenes, defines, reference, ref_spp=None, ref_chunk=None,
                    ref_steps=None, progress=True, scheduler=None, workers=None) -> dict:
    """Reference EXR path per scene (rendered or taken from the cache)."""
    if reference in (None, "none"):
        return {scene: None for scene in scenes}
    refs = {}
    for scene in scenes:
        _, info = render_reference(scene, defines, spp=ref_spp, chunk=ref_chunk,
                                   progress=progress, kind=reference, steps=ref_steps,
                                   scheduler=scheduler, workers=workers)
        refs[scene] = info["path"]
    return refs


def run_job(job, refs, defines, repeats, block, eps) -> dict:
    """:func:`bench_job` of one job description; a failing job is returned
    with its error (picklable: a Dask task of :func:`_run_jobs`)."""
    try:
        return bench_job(job["scene"], job["integrator"], job["params"], defines,
                         refs[job["scene"]], repeats=repeats, block=block, eps=eps)
    except Exception as exc:  # noqa: BLE001 -- recorded, the sweep goes on
        return {"scene": os.path.abspath(job["scene"]), "integrator": job["integrator"],
                "params": job["params"], "error": f"{type(exc).__name__}: {exc}"}


def _run_jobs(jobs, refs, defines, repeats, block, eps, progress, scheduler=None, workers=None):
    """Run the jobs (in this process, or as timed Dask tasks: one timed task
    per machine, see :mod:`episcatter.distributed`); results in job order."""
    import functools

    from .distributed import map_runs

    run = functools.partial(run_job, refs=refs, defines=defines, repeats=repeats,
                            block=block, eps=eps)
    return map_runs(run, jobs, scheduler=scheduler, workers=workers, progress=progress,
                    desc="bench", unit="job", timed=True)


def run_bench(scenes, integrators, sweeps=None, defines=None, reference="exact",
              out_dir="results/bench/bench", repeats=3, params=None, block=1,
              eps=metrics.DEFAULT_EPS, ref_spp=None, ref_chunk=None, ref_steps=None,
              progress=True, name=None, scheduler=None, workers=None) -> list[dict]:
    """Benchmark every integrator on every scene over the cartesian product
    of ``sweeps`` (``{'raymarch.steps': [16, 64], 'spp': [1, 4]}``).

    ``reference``: ``'volpath'`` (cached ground truth, ``ref_spp``
    samples), ``'exact'`` (cached ``raymarch visibility=exact
    steps=ref_steps``) or ``None`` (times only).  Writes ``bench.csv``,
    ``bench.json`` and ``bench.png`` into ``out_dir`` and returns the job
    results (see :func:`bench_job`; failed jobs carry ``error``).
    ``scheduler``/``workers``: run the jobs and the references' chunks on
    Dask (:func:`episcatter.distributed.map_runs`).
    """
    scenes = [os.path.abspath(s) for s in scenes]
    defines = {k: str(v) for k, v in (defines or {}).items()}
    reference = None if reference in (None, "none") else reference
    jobs = expand_jobs(scenes, integrators, params, sweeps)
    refs = make_references(scenes, defines, reference, ref_spp, ref_chunk, ref_steps, progress,
                           scheduler, workers)
    results = _run_jobs(jobs, refs, defines, repeats, block, eps, progress, scheduler, workers)
    os.makedirs(out_dir, exist_ok=True)
    settings = {
        "name": name or os.path.basename(os.path.normpath(out_dir)),
        "scenes": scenes, "integrators": list(integrators), "params": dict(params or {}),
        "sweeps": {k: list(v) for k, v in (sweeps or {}).items()}, "defines": defines,
        "reference": reference, "ref_spp": ref_spp, "ref_chunk": ref_chunk,
        "ref_steps": ref_steps, "repeats": repeats, "block": block, "eps": eps,
        "references": refs,
    }
    write_csv(os.path.join(out_dir, "bench.csv"), results)
    write_json(os.path.join(out_dir, "bench.json"), settings, results)
    plot(os.path.join(out_dir, "bench.png"), results, settings)
    return results


# --------------------------------------------------------------------------
# Output files
# --------------------------------------------------------------------------

def _params_text(params: dict) -> str:
    return " ".join(f"{k}={v}" for k, v in sorted((params or {}).items()))


def _param_names(results) -> list[str]:
    return sorted({k for r in results for k in (r.get("params") or {})})


def _stage_names(results) -> list[str]:
    return sorted({k for r in results for k in (r.get("stages") or {})})


def csv_columns(results) -> list[str]:
    """Columns of bench.csv: the base columns, ``param:<name>`` per
    parameter, ``stage_<name>_s`` per stage, then metrics and error."""
    return (list(BASE_COLUMNS) + [f"param:{p}" for p in _param_names(results)]
            + [f"stage_{s}_s" for s in _stage_names(results)] + list(TAIL_COLUMNS))


def csv_row(result: dict) -> dict:
    """Flatten a job result into a bench.csv row."""
    row = {k: result.get(k, "") for k in BASE_COLUMNS + TAIL_COLUMNS}
    row["scene"] = os.path.basename(result.get("scene", ""))
    row["params"] = _params_text(result.get("params"))
    for k, v in (result.get("params") or {}).items():
        row[f"param:{k}"] = v
    for k, v in (result.get("stages") or {}).items():
        row[f"stage_{k}_s"] = v
    return {k: ("" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()}


def write_csv(path, results) -> None:
    """One row per job (see :func:`csv_columns`); NaN and missing are empty."""
    columns = csv_columns(results)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, restval="")
        writer.writeheader()
        for r in results:
            writer.writerow(csv_row(r))


def _json_safe(value):
    """Strict JSON: non-finite floats -> None, NumPy scalars -> Python."""
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(path, settings, results) -> None:
    """Settings, environment (versions, CPU count, date) and every job result."""
    doc = {"settings": settings, "environment": environment(),
           "timing": {"time_s": "median end-to-end wall time of mi.render (+ eval, sync)",
                      "first_run_s": "warm-up render: kernel compilation + first run",
                      "scattering_s": "median of integrator.timings['scattering']",
                      "scattering_net_s": "scattering_s minus the method's sub-stages "
                                          "(stages other than " + ", ".join(TEMPLATE_STAGES) + ")"},
           "comparison": f"block-averaged over {settings['block']}x{settings['block']} pixels "
                         f"against the {settings['reference']} reference (full layer)",
           "jobs": results}
    with open(path, "w") as f:
        json.dump(_json_safe(doc), f, indent=2)
        f.write("\n")


def plot(path, results, settings) -> None:
    """Log-log time vs relMSE, one series per integrator (per scene if several):
    every setting as a marker, the series' Pareto front (fastest setting for
    each error level) as a line, the reference's own noise as a dashed line."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, ax = plt.subplots(figsize=(6, 4.5), dpi=120)
    several = len({r.get("scene") for r in results}) > 1
    series: dict[str, list] = {}
    for r in results:
        t, e = r.get("time_s"), r.get("relmse")
        if t is None or e is None or not (t > 0 and e > 0):
            continue
        label = r["integrator"] + (f" ({os.path.basename(r['scene'])})" if several else "")
        series.setdefault(label, []).append((t, e, _params_text(r.get("params"))))
    for label, pts in sorted(series.items()):
        front = pareto_front(pts)
        (line,) = ax.plot([p[0] for p in front], [p[1] for p in front], "-", lw=1, alpha=0.6)
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o", color=line.get_color(),
                label=label)
    noise = [r["reference_noise"] for r in results
             if isinstance(r.get("reference_noise"), float) and r["reference_noise"] > 0]
    if series and noise:
        ax.axhline(statistics.median(noise), color="gray", ls="--", lw=1,
                   label="reference noise (relMSE)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("end-to-end time per frame [s] (median)")
    ax.set_ylabel(f"relMSE (eps={settings['eps']:g}, block {settings['block']})")
    ax.set_title(f"{settings['name']}: vs {settings['reference'] or 'no'} reference", fontsize=9)
    if series:
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no errors to plot (no reference, or all zero)",
                ha="center", va="center", transform=ax.transAxes)
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def pareto_front(points):
    """The points (time, error, ...) not beaten in both time and error,
    sorted by time."""
    front, best = [], math.inf
    for p in sorted(points, key=lambda q: (q[0], q[1])):
        if p[1] < best:
            front.append(p)
            best = p[1]
    return front


def format_table(results) -> str:
    """Aligned text table of the job results (for the CLI)."""
    header = ["scene", "integrator", "params", "time [ms]", "scatter [ms]", "first [ms]",
              "relMSE", "FLIP", "error"]
    rows = [header]
    for r in results:
        rows.append([
            os.path.basename(r.get("scene", "")), r.get("integrator", ""),
            _params_text({**(r.get("params") or {}), **({"spp": r["spp"]} if r.get("spp") else {})}),
            _ms(r.get("time_s")), _ms(r.get("scattering_s")),
            _ms(r.get("first_run_s")), _num(r.get("relmse")), _num(r.get("flip")),
            r.get("error", ""),
        ])
    widths = [max(len(str(row[i])) for row in rows) for i in range(len(header))]
    return "\n".join("  ".join(str(c).ljust(w) for c, w in zip(row, widths)).rstrip()
                     for row in rows)


def _ms(seconds) -> str:
    if seconds is None or (isinstance(seconds, float) and math.isnan(seconds)):
        return "-"
    return f"{1000 * seconds:.1f}"


def _num(value) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{value:.4g}"
