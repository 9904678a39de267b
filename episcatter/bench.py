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
of each stage in the render's ``RenderResult.timings`` is also reported (``stage_<name>_s``,
``scattering_s`` = the scattering stage alone, camera capture excluded, the
papers' convention; ``scattering_net_s`` = the median over the runs of the
scattering stage minus the visibility captures built inside it,
:data:`CAPTURE_SUBSTAGES`, e.g. raymarch's shadow map).  Plain Mitsuba
integrators (e.g. ``volpath``) only have the end-to-end time.

Parameters: ``params`` are integrator properties, except ``spp``, which is
passed to ``mi.render`` (0 or absent: the integrator's / scene's own count).
A name ``TYPE.name`` applies only to integrator ``TYPE`` (``raymarch.steps``),
a bare name to every integrator, so one sweep can mix methods whose
properties differ.

Errors are measured with :func:`episcatter.metrics.compare` (scale-free
relMSE unless ``eps_mode="absolute"``) against a reference EXR (its
``full`` layer), after averaging both images over ``block`` x ``block``
pixel blocks, and like for like (:mod:`episcatter.conventions`): with the
default reference, a job rendered at the pixel centres (1 spp) is compared
with the exact marcher at the pixel centres and an antialiased job with an
antialiased reference; each job records both conventions.
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
from .conventions import (ANTIALIASED, PIXEL_CENTRE_CHUNK, PIXEL_CENTRE_SPP, PIXEL_CENTRES,
                          comparison_text, reference_convention, render_convention)
from .reference import environment, load_halves, load_reference, render_reference, render_rgb

SPP_PARAM = "spp"
#: stages of the render template; any other stage in RenderResult.timings is a
#: method's sub-stage of "scattering" (e.g. raymarch's "shadowmap").
TEMPLATE_STAGES = ("validate", "capture", "scattering", "compose", "total")
#: sub-stages of "scattering" that build a visibility capture, which the
#: papers exclude from their times (Baran §10): raymarch's shadow map
CAPTURE_SUBSTAGES = ("shadowmap",)
METRIC_KEYS = ("relmse", "rmse", "mape", "max_error", "max_error_over_peak", "mean_ratio", "flip")
BASE_COLUMNS = (
    "scene", "integrator", "params", "spp", "width", "height", "repeats",
    "load_s", "first_run_s", "time_s", "time_min_s", "time_max_s", "scattering_s", "scattering_net_s",
)
TAIL_COLUMNS = METRIC_KEYS + ("block", "eps", "eps_mode", "convention", "reference",
                              "reference_kind", "reference_spp", "reference_convention",
                              "comparison", "reference_noise", "error")


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


def render_with_stages(scene, integrator, spp: int = 0, seed: int = 0):
    """(finished (H, W, 3) float32 image, stage timings) of one render: an
    episcatter integrator's stage times travel with its ``RenderResult``
    (``render_layers``); any other integrator renders through ``mi.render``
    (no stages)."""
    if not hasattr(integrator, "render_layers"):
        return render_rgb(scene, integrator, spp=spp, seed=seed), {}
    result = integrator.render_layers(scene, 0, seed, spp)
    img = np.array(result[integrator.output], dtype=np.float32)
    if img.shape[-1] == 1:
        img = np.repeat(img, 3, axis=-1)
    return np.ascontiguousarray(img[..., :3]), dict(result.timings)


def _timed_render(scene, integrator, spp, seed=0):
    """(image, wall seconds, integrator stage timings or {})."""
    t0 = time.perf_counter()
    img, stages = render_with_stages(scene, integrator, spp=spp, seed=seed)
    seconds = time.perf_counter() - t0
    return img, seconds, stages


def median_stages(stage_runs: list[dict]) -> dict:
    """Median of each stage present in every run."""
    if not stage_runs:
        return {}
    names = set.intersection(*(set(r) for r in stage_runs))
    return {k: statistics.median(r[k] for r in stage_runs) for k in sorted(names)}


def net_scattering(stages: dict) -> float:
    """One run's scattering stage minus the visibility captures built inside
    it (:data:`CAPTURE_SUBSTAGES`); NaN without a scattering stage."""
    return stages.get("scattering", math.nan) - sum(stages.get(k, 0.0) for k in CAPTURE_SUBSTAGES)


def median_net_scattering(stage_runs: list[dict]) -> float:
    """Median over the runs of :func:`net_scattering` (a difference of
    medians could be negative)."""
    nets = [net_scattering(r) for r in stage_runs if "scattering" in r]
    return statistics.median(nets) if nets else math.nan


def stage_breakdown(timings: dict, wall_s: float) -> tuple[dict, dict]:
    """(top, parts) of one run: ``top`` = the template's stages in order,
    ``other`` (the rest of ``wall_s``: what no stage covers, e.g. copying the
    image out) and ``total`` = ``wall_s``, so the stages sum to the total;
    ``parts`` = the method's sub-stages, all inside ``scattering``."""
    top = {k: timings[k] for k in TEMPLATE_STAGES if k != "total" and k in timings}
    top["other"] = max(wall_s - sum(top.values()), 0.0)
    top["total"] = sum(top.values())
    parts = {k: v for k, v in timings.items() if k not in TEMPLATE_STAGES}
    return top, parts


def _errors(img, reference_path, block, eps, eps_mode=metrics.DEFAULT_EPS_MODE,
            convention=None) -> dict:
    """Metrics of ``img`` against the reference (empty if none), with both
    pixel conventions and whether they match."""
    if not reference_path:
        return {}
    ref, info = load_reference(reference_path)
    result = metrics.compare(img, ref, block=block, eps=eps, eps_mode=eps_mode)
    try:
        noise = metrics.noise_relmse(*load_halves(reference_path), block=block, eps=eps,
                                     eps_mode=eps_mode)
    except KeyError:  # an EXR without the two halves
        noise = math.nan
    ref_convention = reference_convention(info)
    result.update(reference=os.path.abspath(reference_path),
                  reference_kind=info.get("kind"), reference_spp=info.get("spp"),
                  reference_convention=ref_convention, reference_noise=noise)
    if convention:
        result["comparison"] = comparison_text(convention, ref_convention)
    return result


def bench_job(scene_path: str, integrator_type: str, params: dict | None = None,
              defines: dict | None = None, reference_path=None,
              repeats: int = 3, block: int = 1, eps: float = metrics.DEFAULT_EPS,
              seed: int = 0, eps_mode: str = metrics.DEFAULT_EPS_MODE) -> dict:
    """Time one integrator setting on one scene and measure its error.

    Returns a flat dict: the inputs, ``width``/``height``, ``load_s``,
    ``first_run_s`` (warm-up: compile + first run), ``times_s`` (each timed
    run), ``time_s`` (their median), ``time_min_s``, ``time_max_s``,
    ``stages`` (median seconds per stage of ``RenderResult.timings``, empty for
    plain Mitsuba integrators), ``scattering_s`` (the scattering stage, NaN
    without stages), ``scattering_net_s`` (:func:`median_net_scattering`),
    ``convention`` (the render's pixel convention) and, with a reference,
    the keys of :func:`metrics.compare` plus ``reference``,
    ``reference_kind``, ``reference_spp``, ``reference_convention``,
    ``comparison`` (:func:`~episcatter.conventions.comparison_text`) and
    ``reference_noise`` (the reference's own relMSE noise at this block and
    eps, from its two halves: errors below it are not resolved).
    ``reference_path`` is one EXR, ``{convention: EXR}``, or a function of
    the convention returning the EXR, to compare with the reference of the
    job's own convention.  Every run uses the same
    ``seed``; the error is that of the last run.
    """
    from .scene_loading import load_scene, make_integrator

    if int(repeats) < 1:
        raise ValueError(f"repeats = {repeats} must be >= 1.")
    eps = metrics.check_eps(eps, eps_mode)
    props = params_for(integrator_type, params)
    spp = int(props.pop(SPP_PARAM, 0) or 0)
    if spp < 0:
        raise ValueError(f"spp = {spp} must be >= 1 (or 0 for the integrator's / scene's own).")
    t0 = time.perf_counter()
    scene = load_scene(scene_path, defines)
    integrator = make_integrator(integrator_type, props, scene)
    load_s = time.perf_counter() - t0
    convention, spp_used = render_convention(integrator, scene, spp)
    if isinstance(reference_path, dict):
        reference_path = reference_path.get(convention)
    elif callable(reference_path):
        reference_path = reference_path(convention)

    _, first_s, _ = _timed_render(scene, integrator, spp, seed)
    img, times, stage_runs = None, [], []
    for _ in range(int(repeats)):
        img, seconds, stages = _timed_render(scene, integrator, spp, seed)
        times.append(seconds)
        if stages:
            stage_runs.append(stages)
    stages = median_stages(stage_runs)
    result = {
        "scene": os.path.abspath(scene_path), "integrator": integrator_type,
        "params": props, "spp": spp_used, "convention": convention,
        "defines": {k: str(v) for k, v in (defines or {}).items()},
        "width": int(img.shape[1]), "height": int(img.shape[0]),
        "repeats": int(repeats), "seed": int(seed), "load_s": load_s,
        "first_run_s": first_s, "times_s": times, "time_s": statistics.median(times),
        "time_min_s": min(times), "time_max_s": max(times),
        "stages": stages, "scattering_s": stages.get("scattering", math.nan),
        "scattering_net_s": median_net_scattering(stage_runs),
        "block": int(block), "eps": float(eps), "eps_mode": eps_mode,
    }
    if reference_path and props.get("output", "full") != "full":
        result["error"] = (f"output={props['output']} is not comparable with the "
                           "reference's full image; metrics skipped")
        return result
    result.update(_errors(img, reference_path, block, eps, eps_mode, convention))
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


class References:
    """The reference EXR of each (scene, pixel convention), made on first
    use (rendered or taken from the cache).

    ``reference``: ``'volpath'``, ``'exact'`` or ``None``.  With ``ref_spp``
    or ``ref_chunk`` given, or for volpath, one reference per scene whatever
    the job's convention (a mismatch is recorded in the job's
    ``comparison``); otherwise, for ``exact``, each job gets the reference
    of its own convention: the pixel centres (two identical 1-spp chunks)
    or antialiased (the reference module's default spp).  ``scheduler`` /
    ``workers``: render the references' chunks on Dask."""

    def __init__(self, defines, reference, ref_spp=None, ref_chunk=None, ref_steps=None,
                 progress=True, scheduler=None, workers=None):
        self.defines, self.reference = defines, reference
        self.ref_spp, self.ref_chunk, self.ref_steps = ref_spp, ref_chunk, ref_steps
        self.progress, self.scheduler, self.workers = progress, scheduler, workers
        self.fixed = reference == "volpath" or bool(ref_spp) or bool(ref_chunk)
        self.paths: dict[str, dict[str, str]] = {}

    def path(self, scene: str, convention: str) -> str | None:
        """The reference EXR for a job on ``scene`` rendered in ``convention``."""
        if self.reference is None:
            return None
        key = "fixed" if self.fixed else convention
        known = self.paths.setdefault(scene, {})
        if key not in known:
            spp, chunk = self.ref_spp, self.ref_chunk
            if not self.fixed and convention == PIXEL_CENTRES:
                spp, chunk = PIXEL_CENTRE_SPP, PIXEL_CENTRE_CHUNK
            if self.reference == "volpath":
                from .scene_loading import check_volpath_medium, load_scene
                check_volpath_medium(load_scene(scene, self.defines))
            _, info = render_reference(scene, self.defines, spp=spp, chunk=chunk,
                                       progress=self.progress, kind=self.reference,
                                       steps=self.ref_steps, scheduler=self.scheduler,
                                       workers=self.workers)
            known[key] = info["path"]
        return known[key]


def run_job(job, refs: References, defines, repeats, block, eps, eps_mode) -> dict:
    """:func:`bench_job` of one job description, compared with the reference
    of its own pixel convention; a failing job is returned with its error
    (picklable: a Dask task of :func:`_run_jobs`)."""
    try:
        return bench_job(job["scene"], job["integrator"], job["params"], defines,
                         lambda convention: refs.path(job["scene"], convention),
                         repeats=repeats, block=block, eps=eps, eps_mode=eps_mode)
    except Exception as exc:  # noqa: BLE001 -- recorded, the sweep goes on
        return {"scene": os.path.abspath(job["scene"]), "integrator": job["integrator"],
                "params": job["params"], "error": f"{type(exc).__name__}: {exc}"}


def _run_jobs(jobs, refs: References, defines, repeats, block, eps, eps_mode, progress,
              scheduler=None, workers=None):
    """Run the jobs (in this process, or as timed Dask tasks: one timed task
    per machine, see :mod:`episcatter.distributed`); results in job order."""
    import functools

    from .distributed import map_runs

    run = functools.partial(run_job, refs=refs, defines=defines, repeats=repeats,
                            block=block, eps=eps, eps_mode=eps_mode)
    return map_runs(run, jobs, scheduler=scheduler, workers=workers, progress=progress,
                    desc="bench", unit="job", timed=True)


def run_bench(scenes, integrators, sweeps=None, defines=None, reference="exact",
              out_dir="results/bench/bench", repeats=3, params=None, block=1,
              eps=metrics.DEFAULT_EPS, ref_spp=None, ref_chunk=None, ref_steps=None,
              progress=True, name=None, eps_mode=metrics.DEFAULT_EPS_MODE,
              scheduler=None, workers=None) -> list[dict]:
    """Benchmark every integrator on every scene over the cartesian product
    of ``sweeps`` (``{'raymarch.steps': [16, 64], 'spp': [1, 4]}``).

    ``reference``: ``'volpath'`` (cached ground truth, ``ref_spp``
    samples), ``'exact'`` (cached ``raymarch visibility=exact
    steps=ref_steps``; by default at the pixel centres for 1-spp jobs and
    antialiased for the others, see :class:`References`) or ``None``
    (times only).  relMSE is scale-free unless ``eps_mode="absolute"``.  Writes ``bench.csv``,
    ``bench.json`` and ``bench.png`` into ``out_dir`` and returns the job
    results (see :func:`bench_job`; failed jobs carry ``error``).
    ``scheduler``/``workers``: run the jobs and the references' chunks on
    Dask (:func:`episcatter.distributed.map_runs`).
    """
    scenes = [os.path.abspath(s) for s in scenes]
    defines = {k: str(v) for k, v in (defines or {}).items()}
    reference = None if reference in (None, "none") else reference
    jobs = expand_jobs(scenes, integrators, params, sweeps)
    eps = metrics.check_eps(eps, eps_mode)
    refs = References(defines, reference, ref_spp, ref_chunk, ref_steps, progress,
                      scheduler, workers)
    results = _run_jobs(jobs, refs, defines, repeats, block, eps, eps_mode, progress,
                        scheduler, workers)
    os.makedirs(out_dir, exist_ok=True)
    settings = {
        "name": name or os.path.basename(os.path.normpath(out_dir)),
        "scenes": scenes, "integrators": list(integrators), "params": dict(params or {}),
        "sweeps": {k: list(v) for k, v in (sweeps or {}).items()}, "defines": defines,
        "reference": reference, "ref_spp": ref_spp, "ref_chunk": ref_chunk,
        "ref_steps": ref_steps, "repeats": repeats, "block": block, "eps": eps,
        "eps_mode": eps_mode, "relmse_convention": metrics.eps_text(eps, eps_mode),
        "references": refs.paths,
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
                      "scattering_s": "median of RenderResult.timings['scattering']",
                      "scattering_net_s": "median over the runs of the scattering stage minus "
                                          "the visibility captures built inside it ("
                                          + ", ".join(CAPTURE_SUBSTAGES) + ")"},
           "comparison": f"block-averaged over {settings['block']}x{settings['block']} pixels "
                         f"against the {settings['reference']} reference (full layer), "
                         f"{settings['relmse_convention']}; each job's 'comparison' names "
                         "its pixel convention and the reference's",
           "jobs": results}
    with open(path, "w") as f:
        json.dump(_json_safe(doc), f, indent=2)
        f.write("\n")


def plot(path, results, settings) -> None:
    """Log-log time vs relMSE (:func:`draw_plot`) as a PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.8), dpi=120)
    draw_plot(ax, results, settings)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def varying_params(results) -> list[str]:
    """Parameter names (and ``spp``) whose value differs between the jobs:
    what a point's label has to say."""
    names = set(_param_names(results)) | {SPP_PARAM}
    def value(r, k):
        return r.get(SPP_PARAM) if k == SPP_PARAM else (r.get("params") or {}).get(k)
    return sorted(k for k in names if len({repr(value(r, k)) for r in results}) > 1)


def log_axis_limits(values, min_decades: float = 1.0) -> tuple[float, float]:
    """Limits of a log axis around positive ``values``, padded by 20 % and
    widened to at least ``min_decades`` so it always shows labelled ticks."""
    lo, hi = min(values) / 1.2, max(values) * 1.2
    missing = min_decades - math.log10(hi / lo)
    if missing > 0:
        lo, hi = lo / 10 ** (missing / 2), hi * 10 ** (missing / 2)
    return lo, hi


def draw_plot(ax, results, settings) -> None:
    """Time vs relMSE on log-log axes, one series per integrator (per scene if
    several): every setting a labelled marker (its swept parameters), the
    series' Pareto front (fastest setting for each error level) as a line,
    the reference's own noise as a dashed line; ticks at 1, 2, 5 per decade
    with plain labels on both axes."""
    import matplotlib.ticker as ticker

    several = len({r.get("scene") for r in results}) > 1
    ok = [r for r in results if (r.get("time_s") or 0) > 0 and (r.get("relmse") or 0) > 0
          and math.isfinite(r["relmse"])]
    label_keys = varying_params(ok)
    series: dict[str, list] = {}
    for r in ok:
        label = r["integrator"] + (f" ({os.path.basename(r['scene'])})" if several else "")
        text = " ".join(f"{k}={r.get(SPP_PARAM) if k == SPP_PARAM else r['params'].get(k)}"
                        for k in label_keys if k == SPP_PARAM or k in r["params"])
        series.setdefault(label, []).append((r["time_s"], r["relmse"], text))
    for label, pts in sorted(series.items()):
        front = pareto_front(pts)
        (line,) = ax.plot([p[0] for p in front], [p[1] for p in front], "-", lw=1, alpha=0.6)
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o", ms=4, color=line.get_color(),
                label=label)
        for t, e, text in pts:
            if text:
                ax.annotate(text, (t, e), xytext=(3, 3), textcoords="offset points",
                            fontsize=6, color=line.get_color())
    noise = [r["reference_noise"] for r in ok
             if isinstance(r.get("reference_noise"), float) and r["reference_noise"] > 0]
    if series and noise:
        ax.axhline(statistics.median(noise), color="gray", ls="--", lw=1,
                   label="reference noise (relMSE)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    if series:
        ax.set_xlim(*log_axis_limits([r["time_s"] for r in ok]))
        ax.set_ylim(*log_axis_limits([r["relmse"] for r in ok] + noise))
        ax.legend(fontsize=7)
    else:
        ax.text(0.5, 0.5, "no errors to plot (no reference, or all zero)",
                ha="center", va="center", transform=ax.transAxes)
    for axis, fmt in ((ax.xaxis, "{:g}"), (ax.yaxis, "{:.0e}")):
        axis.set_major_locator(ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(ticker.FuncFormatter(lambda v, _, f=fmt: f.format(v)))
        axis.set_minor_locator(ticker.LogLocator(base=10, subs=tuple(range(2, 10))))
        axis.set_minor_formatter(ticker.NullFormatter())
    ax.tick_params(labelsize=7)
    ax.set_xlabel("end-to-end time per frame [s] (median of warm runs)")
    ax.set_ylabel(f"relMSE ({metrics.eps_text(settings['eps'], settings.get('eps_mode', 'relative'))}"
                  f", block {settings['block']})", fontsize=8)
    ax.set_title(f"{settings['name']}: vs {settings['reference'] or 'no'} reference", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)


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
              "relMSE", "mean ratio", "max err/peak", "FLIP", "convention", "error"]
    rows = [header]
    for r in results:
        rows.append([
            os.path.basename(r.get("scene", "")), r.get("integrator", ""),
            _params_text({**(r.get("params") or {}), **({"spp": r["spp"]} if r.get("spp") else {})}),
            _ms(r.get("time_s")), _ms(r.get("scattering_s")),
            _ms(r.get("first_run_s")), _num(r.get("relmse")), _num(r.get("mean_ratio")),
            _num(r.get("max_error_over_peak")), _num(r.get("flip")),
            _convention_cell(r), r.get("error", ""),
        ])
    widths = [max(len(str(row[i])) for row in rows) for i in range(len(header))]
    return "\n".join("  ".join(str(c).ljust(w) for c, w in zip(row, widths)).rstrip()
                     for row in rows)


def _convention_cell(r) -> str:
    """'centres/centres', 'aa/aa', or the mismatch flagged with '!'."""
    short = {PIXEL_CENTRES: "centres", ANTIALIASED: "aa"}
    test, ref = r.get("convention"), r.get("reference_convention")
    if not test:
        return ""
    cell = short.get(test, test) + ("/" + short.get(ref, ref) if ref else "")
    return cell + (" !" if ref and ref != test else "")


def _ms(seconds) -> str:
    if seconds is None or (isinstance(seconds, float) and math.isnan(seconds)):
        return "-"
    return f"{1000 * seconds:.1f}"


def _num(value) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{value:.4g}"
