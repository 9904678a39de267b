"""Time-vs-error frontiers of every method (DESIGN §5) and the error budget.

A method's quality knobs span a settings grid (:func:`settings_grid`, one
registry entry per method, :data:`GRIDS`; a new method plugs in by name
with :func:`register_method`).  Every setting is timed honestly (warm-up render, then the
median of ``repeats`` interleaved timed renders, each finished with
``dr.eval`` + ``dr.sync_thread``) and its error measured with
:func:`episcatter.metrics.scale_free_relmse` in one of two conventions
(DESIGN §2):

``pixel_centre``
    each method's 1-sample-per-pixel image against ``raymarch
    visibility=exact`` at pixel centres (the papers' like-for-like convention);
``antialiased``
    against the box-filtered image (the exact marcher with many jittered
    rays per pixel); every method may take several samples per pixel.

Of all settings, a method keeps its Pareto frontier (:func:`pareto_front`),
and speedups are read off two frontiers at an error level by log-log
interpolation between frontier points (:func:`time_at_error`,
:func:`speedup_at`): a ``>=``/``<=`` bound where a method never reaches the
level inside its sweep (or already beats it at its fastest setting), never an
extrapolation.

Work is cut into independent, picklable tasks (:func:`make_tasks`: one scene
x convention x method, a list of settings each) run by :func:`run_task`, so a
sweep can be spread over processes or Dask workers (``map_fn``).  Within a
task, the settings' timed rounds are interleaved so load changes hit them
alike.  The captures every method needs (camera G-buffer and light
visibility: stages ``capture`` and ``blockers`` / ``shadowmap``) are
reported apart: their sum is the floor no scattering method goes below.
"""
from __future__ import annotations

import itertools
import math
import os
import statistics
import time

import numpy as np

from . import metrics

#: relMSE levels the speedup tables are read at (DESIGN §5)
LEVELS = (1e-3, 1e-4, 1e-5)
CONVENTIONS = ("pixel_centre", "antialiased")
BUDGETS = ("quick", "full")
#: the baseline every speedup is taken against
BASELINE = "raymarch"
#: stages of a method's scattering that capture light visibility
VISIBILITY_STAGES = ("blockers", "shadowmap")
#: volpath is swept only up to this many pixels (it needs thousands of spp)
VOLPATH_MAX_PIXELS = 320 * 240
#: ray-marching steps of the pixel-centre reference and of the antialiased one
REFERENCE_STEPS = {"pixel_centre": 2048, "antialiased": 1024}
#: jittered rays per pixel of the antialiased reference
ANTIALIASED_REFERENCE_SPP = 64


# --------------------------------------------------------------------------
# Settings grids (one registry entry per method)
# --------------------------------------------------------------------------

def grid(**axes) -> list[dict]:
    """Cartesian product of named value lists: ``grid(a=[1, 2], b=[3])`` ->
    ``[{'a': 1, 'b': 3}, {'a': 2, 'b': 3}]``."""
    names = list(axes)
    return [dict(zip(names, combo)) for combo in itertools.product(*axes.values())]


def _raymarch_grid(budget: str, convention: str) -> list[dict]:
    if convention == "pixel_centre":
        if budget == "quick":
            return (grid(visibility=["shadowmap"], steps=[64, 256, 1024],
                         shadowmap_resolution=[1024, 2048])
                    + grid(visibility=["shadowmap"], steps=[2048], shadowmap_resolution=[2048])
                    + grid(visibility=["exact"], steps=[64, 256]))
        # full: the settings that made the 640x480 frontiers, extended towards
        # 1e-5 (finer maps, more steps); exact visibility only where it is
        # affordable at 1280x960
        return (grid(visibility=["shadowmap"], steps=[64, 256, 1024, 2048],
                     shadowmap_resolution=[2048, 4096])
                + grid(visibility=["shadowmap"], steps=[4096], shadowmap_resolution=[4096])
                + grid(visibility=["exact"], steps=[64, 256]))
    if budget == "quick":
        return (grid(visibility=["shadowmap"], steps=[64, 256], shadowmap_resolution=[2048],
                     jitter=[True], spp=[1, 4, 16])
                + grid(visibility=["exact"], steps=[128], jitter=[True], spp=[1, 4, 16]))
    spp = [1, 4, 16, 64]
    return (grid(visibility=["shadowmap"], steps=[64, 256, 1024], shadowmap_resolution=[2048],
                 jitter=[True], spp=spp)
            + grid(visibility=["exact"], steps=[64, 256, 1024], jitter=[True], spp=spp))


def _tree_grid(budget: str, convention: str) -> list[dict]:
    if convention == "pixel_centre":
        if budget == "quick":
            return ([{}]      # the defaults: where a user starts
                    + grid(slice_spacing=[0.5, 1.0, 2.0], light_rays=[0, 512, 1024])
                    + grid(slice_spacing=[4.0], light_rays=[0])
                    + grid(slice_spacing=[1.0, 2.0, 4.0], slice_interpolation=[False])
                    + grid(slice_spacing=[2.0], prefilter=[1])
                    # accurate end: the re-marched samples' segments
                    + grid(slice_spacing=[1.0], ring_steps=[1024]))
        return ([{}]
                + grid(slice_spacing=[0.5, 1.0, 2.0, 4.0], light_rays=[0, 1024],
                       prefilter=[4], slice_interpolation=[True])
                + grid(slice_spacing=[2.0, 4.0], light_rays=[0], prefilter=[4],
                       slice_interpolation=[False])
                + grid(slice_spacing=[2.0], light_rays=[0], prefilter=[1],
                       slice_interpolation=[True])
                # cheap end: where the tree's frontier crosses 1e-3 / 1e-4
                + grid(slice_spacing=[4.0, 8.0], light_rays=[256], prefilter=[4],
                       slice_interpolation=[True])
                + grid(slice_spacing=[8.0], light_rays=[0], prefilter=[4],
                       slice_interpolation=[True])
                # accurate end: where the re-marched samples' 256 segments are
                # the floor (a thin shaft's edges, beam: 6.5e-5 at any slices)
                + grid(slice_spacing=[1.0, 2.0], light_rays=[0], prefilter=[4],
                       slice_interpolation=[True], ring_steps=[1024, 4096]))
    # antialiased: the defaults (slices 1/sqrt(spp) px apart, following the
    # samples) and fixed spacings at each sample count
    if budget == "quick":
        return grid(spp=[1, 4, 16, 64]) + grid(slice_spacing=[1.0, 2.0], spp=[1, 4, 16])
    return grid(spp=[1, 4, 16, 64]) + grid(slice_spacing=[1.0, 2.0, 4.0], spp=[1, 4, 16, 64])


def _fourier_grid(budget: str, convention: str) -> list[dict]:
    if convention == "pixel_centre":
        if budget == "quick":
            return ([{}]
                    + grid(coefficients=[16, 32, 64, 128], weights=["reference_ray", "exact"])
                    + grid(coefficients=[128], weights=["exact"], light_rays=[512, 1024]))
        return ([{}]
                + grid(coefficients=[32, 64, 128, 256], light_rays=[0],
                       weights=["reference_ray", "exact"])
                + grid(coefficients=[128], light_rays=[1024], weights=["exact"]))
    return ([{"spp": n} for n in ([1, 4] if budget == "quick" else [1, 4, 16])]
            + grid(coefficients=[32, 128], weights=["exact"],
                   spp=[1, 4] if budget == "quick" else [1, 4, 16]))


def _minmax_grid(budget: str, convention: str) -> list[dict]:
    """Yusov's three profiles (the talk's slices / samples / map sizes),
    the defaults, and denser integration samples with each refinement
    criterion; one sample per pixel centre in both conventions (the
    method's own convention: it renders pixel centres only)."""
    profiles = grid(profile=["high_quality", "balanced", "high_performance"])
    if convention == "antialiased":
        return [{}] + profiles
    if budget == "quick":
        return [{}] + profiles + grid(initial_step=[4], refinement=["depth", "visibility"])
    return ([{}] + profiles
            + grid(initial_step=[1, 4], refinement=["depth", "visibility"])
            + grid(initial_step=[16], refinement=["visibility", "inscattering"]))


def _volpath_grid(budget: str, convention: str) -> list[dict]:
    if convention == "pixel_centre":
        return []   # a Monte Carlo estimator has no pixel-centre image
    return grid(spp=[16, 64, 256, 1024] if budget == "quick"
                else [16, 64, 256, 1024, 4096, 16384])


#: method name -> grid function (budget, convention) -> list of settings
GRIDS = {"raymarch": _raymarch_grid, "epipolar_tree": _tree_grid,
         "fourier_filter": _fourier_grid, "minmax_epipolar": _minmax_grid,
         "volpath": _volpath_grid}


def register_method(name: str, grid_fn) -> None:
    """Add (or replace) a method's settings grid: ``grid_fn(budget,
    convention)`` returns a list of integrator-property dicts (``spp`` is
    passed to ``mi.render`` instead)."""
    if not callable(grid_fn):
        raise ValueError(f"register_method({name!r}, ...): the grid must be a function "
                         "(budget, convention) -> list of settings dicts.")
    GRIDS[name] = grid_fn


def settings_grid(method: str, budget: str = "quick", convention: str = "pixel_centre",
                  pixels: int | None = None) -> list[dict]:
    """The settings swept for ``method`` (see :data:`GRIDS`).  ``volpath``
    is left out above :data:`VOLPATH_MAX_PIXELS` pixels."""
    if method not in GRIDS:
        raise ValueError(f"No frontier grid for method {method!r}: choose from {sorted(GRIDS)} "
                         "or add one with episcatter.frontier.register_method.")
    if budget not in BUDGETS:
        raise ValueError(f"budget {budget!r} is not one of {BUDGETS}.")
    if convention not in CONVENTIONS:
        raise ValueError(f"convention {convention!r} is not one of {CONVENTIONS}.")
    if method == "volpath" and pixels is not None and pixels > VOLPATH_MAX_PIXELS:
        return []
    return [dict(s) for s in GRIDS[method](budget, convention)]


# --------------------------------------------------------------------------
# Pareto frontier, interpolation, bounds
# --------------------------------------------------------------------------

def usable(time_s, error) -> bool:
    """Whether a (time, error) pair can sit on a log-log frontier (both
    finite and positive; an error of 0 is the reference itself)."""
    return all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0
               for v in (time_s, error))


def pareto_front(points):
    """The points ``(time, error, ...)`` that no other point beats in both
    time and error (ties: the lower error at equal time), sorted by
    increasing time and so by decreasing error.  Unusable points (see
    :func:`usable`) are dropped."""
    front, best = [], math.inf
    for p in sorted((q for q in points if usable(q[0], q[1])), key=lambda q: (q[0], q[1])):
        if p[1] < best:
            front.append(p)
            best = p[1]
    return front


def time_at_error(front, level: float) -> tuple[float, str]:
    """(time, bound) a frontier needs to reach relMSE ``level``.

    ``front`` is :func:`pareto_front`'s output.  Between two frontier points
    the time is interpolated linearly in log(time) against log(error);
    ``'='``.  If even the fastest point is at or below the level, the time is
    at most that point's (``'<='``, the sweep does not say how much faster
    the method could go); if no point reaches the level, at least the
    slowest point's (``'>='``).  Empty frontier: ``(nan, '?')``.
    """
    if not level > 0:
        raise ValueError(f"error level {level!r} must be positive.")
    if not front:
        return math.nan, "?"
    times = [p[0] for p in front]
    errs = [p[1] for p in front]
    if level >= errs[0]:
        return times[0], ("=" if level == errs[0] else "<=")
    if level < errs[-1]:
        return times[-1], ">="
    for i in range(len(front) - 1):
        e0, e1 = errs[i], errs[i + 1]
        if e0 >= level >= e1:
            if level == e1:
                return times[i + 1], "="
            w = (math.log(level) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(times[i]) + w * (math.log(times[i + 1]) - math.log(times[i]))), "="
    raise AssertionError("unreachable: the levels bracket every value")


#: bound of base/test from the bounds of base and test times
_RATIO_BOUND = {("=", "="): "=", (">=", "="): ">=", ("=", "<="): ">=", (">=", "<="): ">=",
                ("<=", "="): "<=", ("=", ">="): "<=", ("<=", ">="): "<="}


def speedup_at(base_front, test_front, level: float) -> dict:
    """Speedup of ``test`` over ``base`` at relMSE ``level``: the ratio of
    the times their frontiers need there (:func:`time_at_error`), with its
    bound: ``'>='`` when the base never gets there or the test is faster
    than its fastest setting, ``'<='`` in the mirror cases, ``'?'`` when both
    bounds point the same way (the ratio is unknown)."""
    tb, bb = time_at_error(base_front, level)
    tt, bt = time_at_error(test_front, level)
    bound = _RATIO_BOUND.get((bb, bt), "?")
    ratio = tb / tt if (math.isfinite(tb) and math.isfinite(tt) and tt > 0) else math.nan
    return {"level": level, "speedup": ratio, "bound": bound,
            "base_time_s": tb, "base_bound": bb, "test_time_s": tt, "test_bound": bt}


def speedup_text(entry: dict) -> str:
    """``'>= 3.2x'`` etc. for a :func:`speedup_at` result (``'-'`` if
    unknown)."""
    s = entry.get("speedup")
    if entry.get("bound") == "?" or s is None or not math.isfinite(s):
        return "-"
    prefix = {"=": "", ">=": ">= ", "<=": "<= "}[entry["bound"]]
    return f"{prefix}{s:.3g}x"


def fronts_by_method(rows, time_key: str = "time_s", error_key: str = "relmse"):
    """``{(scene, convention, method): frontier}`` of run rows; each frontier
    point is ``(time, error, row)``."""
    groups: dict = {}
    for r in rows:
        if r.get("error_message"):
            continue
        t = r.get(time_key)
        if t is None or (isinstance(t, float) and math.isnan(t)):
            t = r.get("time_s")
        groups.setdefault((r["scene"], r["convention"], r["method"]), []).append(
            (t, r.get(error_key), r))
    return {k: pareto_front(v) for k, v in groups.items()}


def speedup_table(rows, levels=LEVELS, baseline: str = BASELINE, time_key: str = "time_s"):
    """One row per scene x convention x method (other than ``baseline``) x
    level: :func:`speedup_at` of its frontier over the baseline's."""
    fronts = fronts_by_method(rows, time_key)
    out = []
    for (scene, conv, method), front in sorted(fronts.items()):
        base = fronts.get((scene, conv, baseline))
        if method == baseline or base is None:
            continue
        for level in levels:
            out.append({"scene": scene, "convention": conv, "method": method,
                        "baseline": baseline, "time_key": time_key,
                        **speedup_at(base, front, level)})
    return out


# --------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------

def scale_free_noise(half_a, half_b, eps: float = metrics.DEFAULT_EPS) -> float:
    """Expected scale-free relMSE of the mean of two independent half
    images against the noise-free image: per pixel ``(a - b)^2 / 4`` (the
    variance of the mean) over the scale-free denominator of the mean."""
    a = np.asarray(half_a, dtype=np.float64)
    b = np.asarray(half_b, dtype=np.float64)
    m = 0.5 * (a + b)
    floor = eps * float(np.mean(m)) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        q = ((a - b) ** 2 / 4.0) / (m ** 2 + floor)
    return float(np.mean(np.where(np.isfinite(q), q, 0.0)))


def image_errors(img, ref) -> dict:
    """``relmse`` (scale-free, DESIGN §2), ``mean_ratio`` (energy) and
    ``max_error_over_peak`` (largest pixel error over the reference's peak)
    of ``img`` against ``ref``, over pixels where both are finite;
    ``nonfinite`` counts the test's non-finite values."""
    img = np.asarray(img, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    if img.shape != ref.shape:
        raise ValueError(f"shape mismatch: image {img.shape} vs reference {ref.shape}; "
                         "render both at the same resolution.")
    ok = np.isfinite(img) & np.isfinite(ref)
    peak = float(np.max(ref[ok])) if ok.any() else math.nan
    return {"relmse": metrics.scale_free_relmse(img[ok], ref[ok]),
            "mean_ratio": metrics.mean_ratio(img[ok], ref[ok]),
            "max_error_over_peak": (float(np.max(np.abs(img[ok] - ref[ok]))) / peak
                                    if peak > 0 else math.nan),
            "nonfinite": int((~np.isfinite(img)).sum())}


def make_reference(scene_path: str, defines: dict, convention: str, progress: bool = True,
                   steps: int | None = None, spp: int | None = None) -> str:
    """Path of the cached reference EXR of a convention (rendered if
    missing): ``raymarch visibility=exact`` at pixel centres (two identical
    one-sample halves, zero noise), or with ``spp`` jittered rays per pixel
    (antialiased; its halves give its own noise)."""
    from .reference import render_reference

    steps = int(steps or REFERENCE_STEPS[convention])
    if convention == "pixel_centre":
        _, info = render_reference(scene_path, defines, spp=2, chunk=1, kind="exact",
                                   steps=steps, progress=progress)
    elif convention == "antialiased":
        spp = int(spp or ANTIALIASED_REFERENCE_SPP)
        if spp < 8:
            raise ValueError(f"antialiased reference spp={spp}: use >= 8 (chunks of >= 4 "
                             "jittered rays; a 1-spp chunk samples the pixel centre)")
        _, info = render_reference(scene_path, defines, spp=spp, chunk=max(4, spp // 8),
                                   kind="exact", steps=steps, progress=progress)
    else:
        raise ValueError(f"convention {convention!r} is not one of {CONVENTIONS}.")
    return info["path"]


# --------------------------------------------------------------------------
# Tasks: one scene x convention x method, a list of settings
# --------------------------------------------------------------------------

def make_tasks(scenes, methods, budget: str, conventions, defines_of, references,
               repeats: int = 3, grids=None) -> list[dict]:
    """The independent, picklable tasks of a sweep.

    ``defines_of(scene, convention)`` gives the ``-D`` defines (resolution)
    of a scene in a convention, ``references[(scene, convention)]`` the
    reference EXR path; ``grids`` (optional) maps a method to a fixed list
    of settings instead of :func:`settings_grid`."""
    tasks = []
    for scene in scenes:
        for conv in conventions:
            defines = {k: str(v) for k, v in defines_of(scene, conv).items()}
            pixels = int(defines.get("res_x", 0) or 0) * int(defines.get("res_y", 0) or 0) or None
            for method in methods:
                settings = (list(grids[method]) if grids and method in grids
                            else settings_grid(method, budget, conv, pixels))
                # a setting without ``spp`` renders one sample per pixel, said
                # explicitly: left out, ``mi.render`` would use the scene's
                # sampler count (the suite's scenes ask for 64)
                settings = [{**s, "spp": int(s.get("spp", 1) or 1)} for s in settings]
                if conv == "pixel_centre":
                    settings = [s for s in settings if s["spp"] == 1]
                if settings:
                    tasks.append({"scene": os.path.abspath(scene), "defines": defines,
                                  "convention": conv, "method": method, "settings": settings,
                                  "reference": references[(scene, conv)],
                                  "repeats": int(repeats)})
    return tasks


def _release_memory() -> None:
    """Hand Dr.Jit's cached free blocks back to the system between timed
    renders (outside the timer): a task keeps every setting's integrator
    alive, and at 1280x960 the blocks cached over a few dozen settings of
    different sizes grew one sweep process past 16 GB.  Every timed render
    then allocates the same way, whatever ran before it."""
    import drjit as dr

    dr.flush_malloc_cache()


def _split_spp(setting: dict) -> tuple[dict, int]:
    props = dict(setting)
    return props, int(props.pop("spp", 0) or 0)


def capture_times(stages: dict) -> dict:
    """The captures inside a render's stage timings: ``camera_capture_s``
    (camera G-buffer), ``visibility_capture_s`` (blocker map or shadow map;
    0 for in-line visibility), their sum ``captures_s``, and
    ``scattering_net_s`` (scattering minus the visibility capture)."""
    camera = stages.get("capture", math.nan)
    vis = sum(stages.get(k, 0.0) for k in VISIBILITY_STAGES)
    return {"camera_capture_s": camera, "visibility_capture_s": vis,
            "captures_s": camera + vis,
            "scattering_net_s": stages.get("scattering", math.nan) - vis}


def run_task(task: dict, progress=None) -> list[dict]:
    """Time and measure every setting of one task (see :func:`make_tasks`).

    Loads the scene once, builds one integrator per setting, renders each
    once as warm-up (``first_run_s``: compilation + first run), then
    ``repeats`` interleaved rounds; ``time_s`` and each stage are medians.
    The error is that of the last image against the task's reference
    (:func:`image_errors`).  A failing setting gives a row with
    ``error_message``.  ``progress``: optional callable, called once per
    finished setting."""
    from .bench import render_with_stages
    from .reference import load_halves, load_reference, render_rgb
    from .scene_loading import load_scene, make_integrator, unwrap_render_error

    ref, info = load_reference(task["reference"])
    try:
        ref_noise = scale_free_noise(*load_halves(task["reference"]))
    except KeyError:
        ref_noise = math.nan
    t0 = time.perf_counter()
    scene = load_scene(task["scene"], task["defines"])
    load_s = time.perf_counter() - t0
    base = {"scene": os.path.basename(task["scene"]), "scene_path": task["scene"],
            "defines": task["defines"], "convention": task["convention"],
            "method": task["method"], "reference": os.path.basename(task["reference"]),
            "reference_spp": info.get("spp"), "reference_noise": ref_noise,
            "repeats": task["repeats"], "load_s": load_s}
    state = []
    for setting in task["settings"]:
        props, spp = _split_spp(setting)
        s = {"setting": setting, "props": props, "spp": spp, "times": [], "stages": []}
        try:
            s["integrator"] = make_integrator(task["method"], props)
            t1 = time.perf_counter()
            render_rgb(scene, s["integrator"], spp=spp)
            s["first"] = time.perf_counter() - t1
            _release_memory()
        except Exception as exc:  # noqa: BLE001 -- recorded, the sweep goes on
            cause = unwrap_render_error(exc)
            s["error"] = f"{type(cause).__name__}: {cause}".replace("\n", " ")
        state.append(s)
    for _ in range(task["repeats"]):
        for s in state:
            if "error" in s:
                continue
            try:
                t1 = time.perf_counter()
                s["image"], stages = render_with_stages(scene, s["integrator"], spp=s["spp"])
                s["times"].append(time.perf_counter() - t1)
                s["stages"].append(stages)
                _release_memory()
            except Exception as exc:  # noqa: BLE001
                s["error"] = f"{type(exc).__name__}: {exc}".replace("\n", " ")
    rows = []
    for s in state:
        row = {**base, "params": s["props"], "spp": s["spp"]}
        if "error" in s:
            row["error_message"] = s["error"]
        else:
            row.update(summarize_times(s["first"], s["times"], s["stages"]))
            row.update(image_errors(s["image"], ref))
            row["width"], row["height"] = int(ref.shape[1]), int(ref.shape[0])
        rows.append(row)
        if progress:
            progress()
    return rows


def summarize_times(first_s: float, times: list, stage_runs: list) -> dict:
    """Medians of timed renders: ``time_s`` (end-to-end), ``scattering_s``,
    each stage (``stage_<name>_s``) and :func:`capture_times`."""
    stage_runs = [r for r in stage_runs if r]
    names = set.intersection(*(set(r) for r in stage_runs)) if stage_runs else set()
    stages = {k: statistics.median(r[k] for r in stage_runs) for k in sorted(names)}
    out = {"first_run_s": first_s, "times_s": list(times), "time_s": statistics.median(times),
           "time_min_s": min(times), "time_max_s": max(times),
           "scattering_s": stages.get("scattering", math.nan)}
    out.update({f"stage_{k}_s": v for k, v in stages.items()})
    if stages:
        out.update(capture_times(stages))
    return out


# --------------------------------------------------------------------------
# Image sizes per budget and convention
# --------------------------------------------------------------------------

#: (width, height) per budget and convention: the antialiased convention
#: renders many jittered rays per pixel (and volpath), hence smaller images
SIZES = {"quick": {"pixel_centre": (640, 480), "antialiased": (160, 120)},
         "full": {"pixel_centre": (1280, 960), "antialiased": (320, 240)}}


def defines_for(budget: str, defines: dict | None = None, sizes: dict | None = None):
    """``defines_of(scene, convention)`` for :func:`make_tasks`: the suite's
    ``res_x``/``res_y`` of :data:`SIZES` (``sizes`` overrides per
    convention) plus the fixed ``defines``."""
    if budget not in SIZES:
        raise ValueError(f"budget {budget!r} is not one of {BUDGETS}.")
    table = {**SIZES[budget], **(sizes or {})}

    def defines_of(scene, convention):
        w, h = table[convention]
        return {**{k: str(v) for k, v in (defines or {}).items()},
                "res_x": str(int(w)), "res_y": str(int(h))}
    return defines_of


# --------------------------------------------------------------------------
# Error budget: the integrators' quality="auto" (integrators.core.quality_auto)
# --------------------------------------------------------------------------

def settings_for_budget(scene, method: str, budget: float) -> dict:
    """Integrator properties of ``method`` that ``quality="auto"`` chooses
    to render the loaded Mitsuba ``scene`` at relMSE <= ``budget``
    (pixel-centre convention against ``raymarch visibility=exact``): the
    probe and rule of :mod:`integrators.core.quality_auto`."""
    from integrators.core.quality_auto import choose

    return choose(scene, method, budget)[0]
