"""``quality="auto"`` fitted on the suite and held out on generated scenes:
``python -m experiments.error_budget [--fit RUNS.json ...] [--fit-only]
[--seeds N] [--size WxH] [--methods ...] [--repeats N] [--no-probe-accuracy]
[--reference-cache DIR] [--march-steps N ...] [--quick]``; ``--merge DIR [DIR ...]
--out OUT``.

1. Fit (:func:`fit_constants`): the exponents and time model of
   :data:`integrators.core.quality_auto.FIT` from the suite's frontier runs
   (pixel centres; ``--fit``, default quick640 and quick160).  ``--fit-only``
   prints them (the committed constants are these, rounded).
2. Hold out: generated scenes (:func:`experiments.random_scenes.random_scene`
   at ``--size``; scenes whose exact reference is black or lit on fewer than
   2 % of the pixels are skipped).  Per scene and method: a sweep of the
   method's knobs (:data:`SWEEPS`) gives its frontier; per budget 1e-3 /
   1e-4 / 1e-5 the ``quality="auto"`` integrator renders, its relMSE is
   measured against the exact pixel-centre reference (``raymarch
   visibility=exact``, 2048 steps) and its time (render alone: the chosen
   settings; with the probe: the warm auto render end to end; medians of
   ``--repeats`` after a warm-up) is compared with the fastest frontier
   setting meeting the achieved error and with the fastest swept setting
   meeting the budget (timed again the same way), and the probe's
   reference marches are timed apart: a rule that rendered only that
   setting would still pay them.

Writes ``results/error_budget/``: ``choices.csv``, ``sweep.csv``,
``budget.json`` and ``table.md``.  ``--merge`` writes the same from runs
already made (:func:`merge_runs`: a held-out set run in parts, or one
method rerun after a change of its rule).
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import statistics
import time

import numpy as np

from episcatter.reference import exact_description, exact_props

NAME = "error_budget"
#: the generated scenes held out (experiments.random_scenes kind)
KIND = "shafts"
REFERENCE = {"type": "raymarch", **exact_props(2048)}
#: what quality_auto's probe marches (plain midpoint rule), at the steps of PROBE_VARIANTS
PROBE_REFERENCE = {"type": "raymarch", "visibility": "exact"}
#: (probe pixels, probe reference steps) whose estimates are compared with the truth
PROBE_VARIANTS = tuple(itertools.product((150, 300, 600, 1200), (256, 512, 1024)))
#: the probe's own pixels: strided ones and the edges of its first
#: setting's image (quality_auto.Strata), as a PROBE_VARIANTS pixels entry
STRATIFIED = "900+300 edges"
ESTIMATE_VARIANTS = PROBE_VARIANTS + tuple((STRATIFIED, n) for n in (256, 512, 1024))
LEVELS = (1e-3, 1e-4, 1e-5)
#: swept settings meeting a budget whose single timing is within this
#: factor of the fastest are timed again as medians (:func:`run_scene`)
RETIMED = 1.25
FIT_RUNS = ["results/frontier/quick640/runs.json", "results/frontier/quick160/runs.json"]
METHODS = ("raymarch", "epipolar_tree", "fourier_filter", "minmax_epipolar")
#: the held-out kinds beyond experiments.random_scenes': ``user`` (experiments.user_scenes),
#: ``mixed`` (odd seeds user-style, even seeds random ``shafts``)
USER_KINDS = ("user", "mixed")


def march_sweep(steps) -> list[dict]:
    """The marcher's swept settings at these step counts (``--march-steps``:
    a scene whose budget no count of the default sweep reaches is
    reachable with more -- the marcher converges to the reference)."""
    return [{"visibility": "exact", "steps": int(n)} for n in sorted(set(steps))]


#: the settings swept on each held-out scene (the frontier a choice is judged on);
#: the tree's light rays as densities (per diagonal pixel)
SWEEPS = {"raymarch": march_sweep((16, 32, 64, 128, 256, 512, 1024)),
          "epipolar_tree": [{"slice_spacing": s, "density": r}
                            for s, r in itertools.product((0.5, 1.4, 4.0), (0.5, 1.4, 4.0))],
          "fourier_filter": [{"coefficients": m} for m in (8, 16, 32, 64, 128, 256)]
          + [{"coefficients": m, "weights": "exact"} for m in (16, 64, 256)],
          "minmax_epipolar": [{"initial_step": s} for s in (1, 2, 4, 8, 16, 32)]}


# --------------------------------------------------------------------------
# Fit
# --------------------------------------------------------------------------

def load_rows(paths) -> list[dict]:
    rows = []
    for path in paths:
        with open(path) as f:
            rows += [r for r in json.load(f)["rows"]
                     if r.get("convention") == "pixel_centre" and not r.get("error_message")
                     and r.get("relmse") and r["relmse"] > 0 and math.isfinite(r["relmse"])]
    return rows


def groups(rows, method, keep):
    """Runs of ``method`` passing ``keep(params)``, per (scene, size)."""
    out = {}
    for r in rows:
        if r["method"] == method and keep(r.get("params") or {}):
            out.setdefault((r["scene"], r.get("width"), r.get("height")), []).append(r)
    return out


def median_slope(pairs_by_group) -> float:
    slopes = []
    for pts in pairs_by_group:
        if len({x for x, _ in pts}) >= 2:
            slopes.append(float(np.polyfit(np.log([x for x, _ in pts]),
                                           np.log([y for _, y in pts]), 1)[0]))
    if not slopes:
        raise ValueError("no frontier runs with two or more knob values to fit from; "
                         "run the frontier sweep first (python -m experiments.frontier)")
    return float(np.median(slopes))


def tree_density(r) -> float:
    diag = math.hypot(r["width"], r["height"])
    lr = r["params"].get("light_rays", 0) or max(32.0, diag)
    return lr / diag


def fit_tree(rows) -> dict:
    """Exponents a, b of relMSE = A s^a + B rho^-b (A, B per scene, least
    squares on relative residuals over a grid of a, b) and the time model
    t = alpha + beta/s + gamma rho/s (per scene normalised by its mean)."""
    g = groups(rows, "epipolar_tree",
               lambda p: "slice_interpolation" not in p and "prefilter" not in p)
    best = None
    for a in np.arange(0.5, 3.01, 0.1):
        for b in np.arange(0.3, 3.01, 0.1):
            cost = 0.0
            for runs in g.values():
                s = np.array([r["params"]["slice_spacing"] for r in runs])
                rho = np.array([tree_density(r) for r in runs])
                e = np.array([r["relmse"] for r in runs])
                X = np.stack([s ** a, rho ** -b], 1) / e[:, None]
                coef = np.clip(np.linalg.lstsq(X, np.ones(len(e)), rcond=None)[0], 0, None)
                cost += float(np.sum(np.log(np.maximum(X @ coef, 1e-12)) ** 2))
            if best is None or cost < best[0]:
                best = (cost, float(a), float(b))
    X, y = [], []
    for runs in g.values():
        t = np.array([r["time_s"] for r in runs])
        for r, tt in zip(runs, t / t.mean()):
            s, rho = r["params"]["slice_spacing"], tree_density(r)
            X.append([1.0, 1.0 / s, rho / s])
            y.append(tt)
    coef = np.clip(np.linalg.lstsq(np.array(X), np.array(y), rcond=None)[0], 0, None)
    return {"a": round(best[1], 2), "b": round(best[2], 2),
            "time": tuple(round(float(c / coef.sum()), 3) for c in coef)}


def fit_constants(rows) -> dict:
    """:data:`integrators.core.quality_auto.FIT` from frontier run rows."""
    march = groups(rows, "raymarch", lambda p: p.get("visibility") == "exact")
    filt = groups(rows, "fourier_filter",
                  lambda p: "light_rays" not in p and p.get("weights") == "reference_ray")
    return {"raymarch": {"k": round(median_slope(
                [[(r["params"]["steps"], r["relmse"]) for r in v] for v in march.values()]), 2),
                "k_range": (-4.0, -1.0)},
            "epipolar_tree": fit_tree(rows),
            "fourier_filter": {"k": round(median_slope(
                [[(r["params"]["coefficients"], r["relmse"]) for r in v]
                 for v in filt.values()]), 2)}}


# --------------------------------------------------------------------------
# Held out
# --------------------------------------------------------------------------

def timed(scene, integrator, repeats):
    """(image, median time) of ``repeats`` renders after a warm-up (DESIGN §5)."""
    from episcatter.reference import render_rgb

    return median_time(lambda: render_rgb(scene, integrator, spp=1), repeats)


def median_time(render, repeats):
    """(last result, median time) of ``repeats`` calls of ``render`` after a
    warm-up call."""
    out = render()
    times = []
    for _ in range(max(repeats, 1)):
        t0 = time.perf_counter()
        out = render()
        times.append(time.perf_counter() - t0)
    return out, statistics.median(times)


def auto_render(scene, auto):
    """The ``quality="auto"`` integrator's RenderResult, evaluated and
    synchronised (its time is the user's: probe and render)."""
    import drjit as dr

    res = auto.render_layers(scene, spp=1)
    dr.eval(res["full"])
    dr.sync_thread()
    return res


def reference_time(scene, method, budget, image, repeats) -> float:
    """Median time of the probe's reference marches for ``budget`` (the
    tier of :func:`~integrators.core.quality_auto.budget_probe`, on
    the pixels it would take: stratified on ``image``, except for the
    marcher, whose probe renders partial images and keeps its strided
    pixels): what even a rule that rendered only the best setting would
    pay to measure it."""
    from integrators.core import quality_auto as qa

    def march():
        probe = qa.budget_probe(scene, 0, method, {}, budget)
        if method != "raymarch":
            probe.stratify(image)
        return probe.reference
    return median_time(march, repeats)[1]


def cached_reference(cache, name, size, render):
    """The held-out reference of scene ``name`` at ``size``: ``render()``,
    kept in directory ``cache`` (None: not kept) for later runs."""
    if cache is None:
        return render()
    import hashlib

    key = hashlib.sha1(f"{name} {size[0]}x{size[1]} {exact_description(2048)}".encode())
    path = os.path.join(cache, key.hexdigest()[:20] + ".npy")
    if os.path.isfile(path):
        return np.load(path)
    ref = np.asarray(render(), np.float32)
    os.makedirs(cache, exist_ok=True)
    np.save(path, ref)
    return ref


def release_memory() -> None:
    """Free what one scene's renders left behind: Python's cycles, and the
    memory Dr.Jit keeps for reuse (its allocation cache).  Without it a
    run of three methods at 640x480 grew past 24 GB over 30 scenes and
    was killed."""
    import gc

    import drjit as dr

    gc.collect()
    dr.flush_malloc_cache()


def explicit(method, setting, diagonal) -> dict:
    """Integrator properties of a sweep setting (the tree's density -> light rays)."""
    from integrators.tree.quality import light_rays_of

    s = dict(setting)
    if "density" in s:
        s["light_rays"] = light_rays_of(s.pop("density"), diagonal)
    return {"type": method, **s}


def usable_reference(ref) -> str | None:
    """Why a reference cannot judge a method (black, non-finite, hardly lit), or None."""
    if not np.all(np.isfinite(ref)):
        return "non-finite reference"
    peak = float(ref.max())
    if peak <= 0:
        return "black reference"
    lit = float(np.mean(ref.max(axis=-1) > 1e-2 * peak))
    return None if lit >= 0.02 else f"lit on {lit:.1%} of the pixels"


#: a held-out scene is kept only if the cheapest marcher misses this relMSE
#: (the budget matters on it)
HARD_LEVEL = 1e-4
CHEAPEST = {"type": "raymarch", "visibility": "exact", "steps": 16}


def scene_spec(seed: int, kind: str):
    """The held-out scene of ``seed``: ``random_scene(seed, kind)``, a
    user-style scene (``user``: :func:`experiments.user_scenes.user_scene`)
    or, ``mixed``, one or the other by the seed's parity."""
    from experiments.random_scenes import random_scene
    from experiments.user_scenes import user_scene

    if kind == "user" or (kind == "mixed" and seed % 2):
        return user_scene(seed)
    return random_scene(seed, KIND if kind == "mixed" else kind)


def held_out_scenes(n, first_seed, size, kind=KIND, cache=None):
    """(name, scene spec at ``size``, reference) of the first ``n`` usable
    seeds of :func:`scene_spec`: reference finite and lit, and the cheapest
    marcher (:data:`CHEAPEST`) missing :data:`HARD_LEVEL`.  The specs, not
    the loaded scenes: each is loaded when its turn comes and dropped after
    (dozens of scenes held at once made every render 1.5x slower).
    ``cache``: a directory keeping the references for later runs."""
    import mitsuba as mi

    from episcatter import frontier as fr
    from episcatter.reference import render_rgb

    from tqdm.auto import tqdm

    out, seed, skipped = [], first_seed, []
    with tqdm(total=n, desc="held-out scenes (references)", unit="scene") as bar:
        while len(out) < n and seed < first_seed + 20 * n:
            spec = scene_spec(seed, kind).at_resolution(*size)
            seed += 1
            scene = spec.load()
            ref = cached_reference(cache, spec.name, size,
                                   lambda: render_rgb(scene, mi.load_dict(REFERENCE), spp=1))
            why = usable_reference(ref)
            if not why:
                e = fr.image_errors(render_rgb(scene, mi.load_dict(CHEAPEST), spp=1),
                                    ref)["relmse"]
                why = None if e > HARD_LEVEL else f"16 steps already at relMSE {e:.2g}"
            bar.set_postfix_str(f"{spec.name}: {why or 'kept'}; {len(skipped)} skipped")
            if why:
                skipped.append((spec.name, why))
                continue
            out.append((spec.name, spec, ref))
            del scene
            bar.update(1)
    return out, skipped


def probe_accuracy(name, method, scene, ref, images, refs):
    """The probe's estimate against the truth (task 3): for each setting
    the rule probes, its full-image relMSE against ``ref`` and the subset
    estimate for every (pixels, reference steps) of :data:`PROBE_VARIANTS`
    (``refs``: steps -> full exact-marcher image; ``images``: settings key
    -> full image of that setting)."""
    from episcatter import frontier as fr
    from integrators.core import quality_auto as qa

    h, w = ref.shape[:2]
    rows = []
    first = next(iter(images.values()), None)
    strata = (qa.Strata(qa.probe_pixels(w, h, qa.PROBE_PIXELS - qa.EDGE_PIXELS),
                        qa.edge_pixels(first), w * h, qa.EDGE_PIXELS)
              if first is not None else None)
    for key, img in images.items():
        true = fr.image_errors(img, ref)["relmse"]
        flat = img.reshape(-1, img.shape[-1])
        for pixels, steps in ESTIMATE_VARIANTS:
            idx, wts = ((strata.pixels, strata.weights) if pixels == STRATIFIED else
                        (qa.probe_pixels(w, h, pixels), None))
            est = qa.subset_relmse(flat[idx], refs[steps].reshape(-1, img.shape[-1])[idx],
                                   weights=wts)
            rows.append({"scene": name, "method": method, "settings": key, "pixels": pixels,
                         "pixels_used": len(idx),
                         "reference_steps": steps, "true_relmse": true, "estimate": est,
                         "estimate_over_true": est / true if true > 0 else float("nan")})
    return rows


def probe_reference_times(name, scene) -> list[dict]:
    """Time of the probe's reference (the exact marcher on the subset, the
    probe's dominant cost) per :data:`PROBE_VARIANTS`, after a warm-up."""
    from integrators.core import quality_auto as qa

    rows = []
    for pixels, steps in PROBE_VARIANTS:
        qa.Probe(scene, 0, "raymarch", {}, pixels, steps).reference
        t0 = time.perf_counter()
        qa.Probe(scene, 0, "raymarch", {}, pixels, steps).reference
        rows.append({"scene": name, "method": "reference", "pixels": pixels,
                     "reference_steps": steps, "time_s": time.perf_counter() - t0})
    return rows


def run_scene(name, scene, ref, methods, repeats, log, probe_accuracy_rows=True, sweeps=None):
    """(choices, sweep, probe rows) of one held-out scene (module doc):
    each swept setting timed once after a warm-up; per budget the auto
    render (probe included), its chosen setting, and the fastest swept
    settings that meet the budget (those within :data:`RETIMED` of the
    fastest) timed again as medians of ``repeats`` after a warm-up, so
    that the ratios compare medians taken in one process; the probe's
    estimates against the truth (``probe_accuracy_rows``) cost three
    full-image marches per scene; ``sweeps``: the settings swept per method
    (default :data:`SWEEPS`)."""
    import mitsuba as mi

    from episcatter import frontier as fr
    from episcatter.reference import render_rgb
    from integrators.core import quality_auto as qa

    h, w = ref.shape[:2]
    diag = math.hypot(w, h)
    choices, sweep, probes = [], [], []
    refs = ({n: render_rgb(scene, mi.load_dict({**PROBE_REFERENCE, "steps": n}), spp=1)
             for n in sorted({st for _, st in PROBE_VARIANTS})} if probe_accuracy_rows else {})
    for method in methods:
        if probe_accuracy_rows:
            try:
                images = {json.dumps(p, sort_keys=True):
                          render_rgb(scene, mi.load_dict({"type": method, **p}), spp=1)
                          for p in qa.probe_settings(method, diag)}
                probes += probe_accuracy(name, method, scene, ref, images, refs)
                if method == methods[0]:
                    probes += probe_reference_times(name, scene)
            except ValueError as exc:
                log(f"{name} {method} probe: {exc}")
        pts, swept = [], []
        try:
            for setting in (sweeps or SWEEPS)[method]:
                props = explicit(method, setting, diag)
                img, t = timed(scene, mi.load_dict(props), 1)
                e = fr.image_errors(img, ref)["relmse"]
                pts.append((t, e))
                swept.append((props, t, e))
                sweep.append({"scene": name, "method": method,
                              "settings": {k: v for k, v in props.items() if k != "type"},
                              "time_s": t, "relmse": e})
        except ValueError as exc:
            log(f"{name} {method}: {exc}")
            continue
        front = fr.pareto_front(pts)
        retimed = {}

        def median_of(props):
            key = json.dumps(props, sort_keys=True)
            if key not in retimed:
                retimed[key] = timed(scene, mi.load_dict(props), repeats)[1]
            return retimed[key]

        for budget in LEVELS:
            auto = mi.load_dict({"type": method, "quality": "auto", "error_budget": budget})
            res, t_auto = median_time(lambda: auto_render(scene, auto), repeats)
            settings = res.stats["auto_settings"]
            img_e, t = timed(scene, mi.load_dict({"type": method, **settings}), repeats)
            img = np.asarray(res["full"])
            err = fr.image_errors(img, ref)
            bit_same = bool(np.array_equal(img, img_e))
            best_t, bound = (fr.time_at_error(front, err["relmse"]) if err["relmse"] > 0
                             else (float("nan"), "?"))
            # the fastest known setting that meets the budget (nan: none does):
            # a swept one (the fastest few timed again as medians), or the
            # rule's own choice where no swept setting does (the filter's
            # defaults for a directional light)
            meet = [(t_s, p) for p, t_s, e_s in swept if e_s <= budget]
            fastest = min((t_s for t_s, _ in meet), default=float("nan"))
            meeting = [median_of(p) for t_s, p in meet if t_s <= RETIMED * fastest]
            meeting += [t] if err["relmse"] <= budget else []
            t_meet = min(meeting) if meeting else float("nan")
            t_ref = reference_time(scene, method, budget, img.reshape(ref.shape), repeats)
            row = {"scene": name, "method": method, "budget": budget, "settings": settings,
                   "probe": res.stats["auto_probe"], "probe_s": res.stats["auto_probe_s"],
                   "time_s": t, "time_with_probe_s": t_auto, "relmse": err["relmse"],
                   "error_over_budget": err["relmse"] / budget,
                   "same_as_explicit": bit_same,
                   "cheapest_sweep_relmse": min(pts)[1],
                   "best_sweep_relmse": min(e for _, e in pts),
                   "best_known_relmse": min([e for _, e in pts] + [err["relmse"]]),
                   "frontier_time_at_error_s": best_t, "frontier_bound": bound,
                   "time_over_frontier": t / best_t if best_t else float("nan"),
                   "flagged": bool(res.stats.get("auto_over_budget")),
                   "best_meeting_time_s": t_meet,
                   "time_over_best_meeting": t / t_meet,
                   "time_with_probe_over_best_meeting": t_auto / t_meet,
                   "probe_reference_s": t_ref,
                   "oracle_over_best_meeting": (t_meet + t_ref) / t_meet,
                   "time_with_probe_over_frontier": t_auto / best_t if best_t else float("nan")}
            choices.append(row)
            log(f"{name} {method} {budget:g}: {settings} relMSE {err['relmse']:.3g} "
                f"({row['error_over_budget']:.2f}x) t {t:.3g} s (+probe {t_auto:.3g} s) "
                f"frontier {bound} {best_t:.3g} s")
    return choices, sweep, probes


def summarize(choices) -> dict:
    """Per method: share of cases with relMSE <= 2x budget, in [budget/2, 2
    budget], time (without / with the probe) <= 2x the frontier's at the
    achieved error (a ">=" bound -- the sweep never got that accurate --
    makes the ratio an upper bound); the same on the cases where the
    budget matters (the sweep's cheapest setting misses it)."""
    out = {}
    for method in sorted({c["method"] for c in choices}):
        sel = [c for c in choices if c["method"] == method]
        n = len(sel)
        ok = lambda key: sum(c[key] <= 2 for c in sel) / n
        hard = [c for c in sel if c["cheapest_sweep_relmse"] > c["budget"]]
        out[method] = {"cases": n, "scenes": len({c["scene"] for c in sel}),
                       "hard_cases": len(hard),
                       "hard_error_le_2x_budget": (sum(c["error_over_budget"] <= 2 for c in hard)
                                                   / len(hard) if hard else float("nan")),
                       "hard_time_le_2x_frontier": (sum(c["time_over_frontier"] <= 2
                                                        for c in hard) / len(hard)
                                                    if hard else float("nan")),
                       "error_le_2x_budget": sum(c["error_over_budget"] <= 2 for c in sel) / n,
                       "error_within_2x_either_way":
                           sum(0.5 <= c["error_over_budget"] <= 2 for c in sel) / n,
                       "time_le_2x_frontier": ok("time_over_frontier"),
                       "time_with_probe_le_2x_frontier": ok("time_with_probe_over_frontier"),
                       "median_time_over_frontier":
                           statistics.median(c["time_over_frontier"] for c in sel),
                       "median_time_with_probe_over_frontier":
                           statistics.median(c["time_with_probe_over_frontier"] for c in sel),
                       "same_as_explicit": sum(c["same_as_explicit"] for c in sel) / n}
        out[method].update(_reach_shares(sel))
        for b in LEVELS:
            sb = [c for c in sel if c["budget"] == b]
            out[method][f"error_le_2x_budget_{b:g}"] = (sum(c["error_over_budget"] <= 2
                                                            for c in sb) / len(sb))
            out[method][f"by_budget_{b:g}"] = _reach_shares(sb)
    return out


def _reach_shares(sel) -> dict:
    """The issue's measures on the cases ``sel``: of those some known
    setting (a swept one, or the rule's choice) meets the budget
    (*reachable*), the share within 2x of the budget, the share within 2x
    or flagged (``stats["auto_over_budget"]``), and the share whose time
    (alone, and with the probe) is within 2x of the fastest known setting
    meeting the budget; of the others, how many were flagged and how many
    ended over 2x the budget unflagged (*missed*)."""
    best = lambda c: c.get("best_known_relmse", c["best_sweep_relmse"])
    reach = [c for c in sel if best(c) <= c["budget"]]
    n = len(reach)
    share = (lambda f: sum(bool(f(c)) for c in reach) / n) if n else (lambda f: float("nan"))
    return {"reachable": n, "unreachable": len(sel) - n,
            "unreachable_flagged": sum(c.get("flagged", False) for c in sel
                                       if best(c) > c["budget"]),
            "unreachable_missed": sum(not c.get("flagged", False)
                                      and c["error_over_budget"] > 2 for c in sel
                                      if best(c) > c["budget"]),
            "within_2x": share(lambda c: c["error_over_budget"] <= 2),
            "within_2x_or_flagged": share(lambda c: c["error_over_budget"] <= 2
                                          or c.get("flagged", False)),
            "time_le_2x_best_meeting": share(lambda c: c["time_over_best_meeting"] <= 2),
            "time_with_probe_le_2x_best_meeting":
                share(lambda c: c["time_with_probe_over_best_meeting"] <= 2),
            # a rule that rendered only the best setting and measured it
            # against the probe's reference (older runs: not measured)
            "oracle_le_2x_best_meeting":
                share(lambda c: c.get("oracle_over_best_meeting", math.nan) <= 2)}


def summarize_probes(probes) -> list[dict]:
    """Per (method, probe pixels, reference steps): the estimate's error
    against the true relMSE (median and 90th percentile of
    |log2(estimate / true)|, share within 2x) and the reference's time."""
    est = [p for p in probes if p["method"] != "reference" and p["true_relmse"] > 0]
    times = {}
    for p in probes:
        if p["method"] == "reference":
            times.setdefault((p["pixels"], p["reference_steps"]), []).append(p["time_s"])
    out = []
    for method in sorted({p["method"] for p in est}):
        for pixels, steps in ESTIMATE_VARIANTS:
            sel = [p for p in est if p["method"] == method and p["reference_steps"] == steps
                   and p["pixels"] == pixels]
            if not sel:
                continue
            err = np.abs(np.log2([max(p["estimate"], 1e-30) / p["true_relmse"] for p in sel]))
            t = times.get((pixels, steps), [])
            out.append({"method": method, "pixels": pixels, "reference_steps": steps,
                        "cases": len(sel), "median_abs_log2": float(np.median(err)),
                        "p90_abs_log2": float(np.percentile(err, 90)),
                        "within_2x": float(np.mean(err <= 1.0)),
                        "median_reference_s": statistics.median(t) if t else float("nan")})
    return out


def probe_table(rows) -> list[str]:
    lines = ["| method | probe pixels | reference steps | cases | median abs log2(est/true) | "
             "90th pct | within 2x | reference time [s] |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['pixels']} | {r['reference_steps']} | {r['cases']} | "
                     f"{r['median_abs_log2']:.2f} | {r['p90_abs_log2']:.2f} | "
                     f"{r['within_2x']:.0%} | {r['median_reference_s']:.3g} |")
    return lines


SHAFTS_DRAWN = (
    "Held-out scenes: `experiments.random_scenes.random_scene(seed, kind=\"shafts\")` (a kind "
    "no seed of the stress cycle draws): homogeneous medium box with σt·B log-uniform in "
    "[0.3, 30], 3-8 box/sphere occluders in the view frustum (for point/spot lights between "
    "the light and a point in view), a directional light 20-160° off the view axis or a "
    "point/spot light inside the frustum, fov 35-80°, pixel centres; a seed is kept only if "
    "its reference (`" + exact_description(2048) + "`) is finite, lit on >= 2 % of the "
    "pixels and the cheapest marcher (16 exact steps) misses relMSE 1e-4 (the budget "
    "matters).  The rule was fitted on the suite's frontier runs (results/frontier/quick640, "
    "quick160), none of these scenes.")


USER_DRAWN = (
    "`experiments.user_scenes.user_scene(seed)`: scenes written the way users write them, "
    "five archetypes in turn -- a room lit by the sun through a barred window, a (textured) "
    "spot light above a lattice of thin bars, a point light in view among columns, a low sun "
    "behind a colonnade, the sun through a canopy of leaves -- σt·S log-uniform in [0.1, 10] "
    "(thin haze to thick fog), albedo 0.3-1, coloured σt one time in four, isotropic or "
    "Henyey-Greenstein phase (g up to 0.6); kept on the same tests as the random scenes.")


def how_drawn(kind: str) -> str:
    """The held-out set's description for the report."""
    if kind == "user":
        return "Held-out scenes: " + USER_DRAWN
    if kind == "mixed":
        return ("Held-out scenes, odd seeds: " + USER_DRAWN + "  Even seeds: "
                + SHAFTS_DRAWN[len("Held-out scenes: "):])
    return SHAFTS_DRAWN


def report(summary, fit, command, skipped, probes=(), kind: str = KIND) -> str:
    lines = [f"Command: `{command}`", "", how_drawn(kind), "",
             "| method | scenes | cases | relMSE <= 2x budget (1e-3 / 1e-4 / 1e-5) | "
             "in [budget/2, 2 budget] | time <= 2x frontier | with probe | "
             "median time / frontier (with probe) | budget matters: cases, "
             "relMSE <= 2x budget, time <= 2x frontier | sweep reaches the budget: cases, "
             "relMSE <= 2x budget |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for m, s in summary.items():
        per = " / ".join(f"{s[f'error_le_2x_budget_{b:g}']:.0%}" for b in LEVELS)
        lines.append(f"| {m} | {s['scenes']} | {s['cases']} | {s['error_le_2x_budget']:.0%} "
                     f"({per}) | {s['error_within_2x_either_way']:.0%} | "
                     f"{s['time_le_2x_frontier']:.0%} | {s['time_with_probe_le_2x_frontier']:.0%}"
                     f" | {s['median_time_over_frontier']:.2f} "
                     f"({s['median_time_with_probe_over_frontier']:.2f}) | {s['hard_cases']}, "
                     f"{s['hard_error_le_2x_budget']:.0%}, {s['hard_time_le_2x_frontier']:.0%} | "
                     f"{s['reachable']}, {s['within_2x']:.0%} |")
    lines += ["", "Per budget, on the cases some swept setting meets the budget: achieved "
              "relMSE <= 2x the budget (or flagged over budget), and the time -- alone and "
              "with the probe -- <= 2x the fastest known setting that meets the budget (a "
              "swept one or the rule's own choice); the share where even a rule that "
              "rendered only that setting and measured it against the probe's reference "
              "(its marches timed apart) would be within 2x; the cases no known setting "
              "meets, how many of them were flagged, and how many ended over 2x the budget "
              "unflagged:",
              "",
              "| method | budget | reachable | relMSE <= 2x | or flagged | time <= 2x best "
              "meeting | with probe | best + probe reference <= 2x best | unreachable "
              "(flagged; > 2x unflagged) |",
              "|---|---|---|---|---|---|---|---|---|"]
    for m, s in summary.items():
        for b in LEVELS + ("all",):
            r = s if b == "all" else s[f"by_budget_{b:g}"]
            lines.append(f"| {m} | {b if b == 'all' else f'{b:g}'} | {r['reachable']} | "
                         f"{r['within_2x']:.0%} | {r['within_2x_or_flagged']:.0%} | "
                         f"{r['time_le_2x_best_meeting']:.0%} | "
                         f"{r['time_with_probe_le_2x_best_meeting']:.0%} | "
                         f"{r.get('oracle_le_2x_best_meeting', math.nan):.0%} | "
                         f"{r['unreachable']} ({r['unreachable_flagged']}; "
                         f"{r.get('unreachable_missed', '?')}) |")
    if probes:
        lines += ["", "Probe estimate vs true relMSE (the rule's probe settings, full-image "
                  "renders; subsets and shorter reference marches cut from them):", ""]
        lines += probe_table(summarize_probes(probes))
    lines += ["", f"fitted constants: {fit}", "",
              f"skipped scenes: {len(skipped)} ({'; '.join(f'{n}: {w}' for n, w in skipped)})",
              "", "Per case: choices.csv; sweeps: sweep.csv."]
    return "\n".join(lines) + "\n"


def write_results(out, choices, sweep, fit, command, skipped, settings, probes=()) -> str:
    """choices.csv, sweep.csv, budget.json and table.md; the table's text."""
    from episcatter.frontier_report import environment, write_rows_csv

    write_rows_csv(os.path.join(out, "choices.csv"), choices)
    write_rows_csv(os.path.join(out, "sweep.csv"), sweep)
    if probes:
        write_rows_csv(os.path.join(out, "probe.csv"), probes)
    summary = summarize(choices)
    with open(os.path.join(out, "budget.json"), "w") as f:
        json.dump({"settings": settings, "environment": environment(), "summary": summary,
                   "probe": summarize_probes(probes) if probes else []},
                  f, indent=1, default=str)
    text = report(summary, fit, command, skipped, probes, settings.get("kind", KIND))
    with open(os.path.join(out, "table.md"), "w") as f:
        f.write(text)
    return text


def scene_seed(name: str) -> int:
    """The seed in a held-out scene's name (``"seed 2010 (...)"``, ``"user
    2011 (...)"``)."""
    return int(name.split()[1])


def merge_runs(dirs, out, command: str, first_seed: int | None = None,
               count: int | None = None, methods=METHODS) -> str:
    """Merge the results of runs ``dirs`` (each one an ``--out`` of this
    module) into ``out``: per (scene, method), the rows of the last run in
    ``dirs`` that has them -- the same scene under a rule changed since is
    the later run's -- with each run's settings in ``budget.json``; the
    table's text.  ``first_seed``, ``count``: only the scenes of seeds from
    ``first_seed`` on, the first ``count`` of them (the held-out set a run
    of ``--seeds count --first-seed first_seed`` draws); ``methods``: only
    theirs."""
    from episcatter.frontier_report import read_rows_csv

    choices, sweep, settings, skipped = {}, {}, [], {}
    for d in dirs:
        with open(os.path.join(d, "budget.json")) as f:
            s = json.load(f)["settings"]
        settings.append({"run": d, **s})
        for name, why in s.get("skipped", []):
            skipped[name] = why
        for key, rows in (("choices", choices), ("sweep", sweep)):
            got = {}
            for r in read_rows_csv(os.path.join(d, f"{key}.csv")):
                if r["method"] in methods:
                    got.setdefault((r["scene"], r["method"]), []).append(r)
            rows.update(got)
    if not choices:
        raise ValueError(f"no choices.csv rows in {list(dirs)}: give the --out folders of "
                         "runs of this module.")
    names = sorted({n for n, _ in choices}, key=scene_seed)
    if first_seed is not None:
        names = [n for n in names if scene_seed(n) >= first_seed]
    kept = set(names[:count] if count else names)
    if not kept:
        raise ValueError(f"no scene of seed {first_seed} or later in {list(dirs)}: lower "
                         "--first-seed.")
    choices = {k: v for k, v in choices.items() if k[0] in kept}
    sweep = {k: v for k, v in sweep.items() if k[0] in kept}
    last = max(scene_seed(n) for n in kept)
    skipped = {n: w for n, w in skipped.items()
               if (first_seed is None or scene_seed(n) >= first_seed) and scene_seed(n) < last}
    os.makedirs(out, exist_ok=True)
    kinds = {s.get("kind", KIND) for s in settings}
    merged = {"merged_from": settings, "kind": kinds.pop() if len(kinds) == 1 else "mixed",
              "seeds": sorted(kept, key=scene_seed),
              "methods": sorted({m for _, m in choices})}
    return write_results(out, [r for rows in choices.values() for r in rows],
                         [r for rows in sweep.values() for r in rows],
                         settings[-1].get("fitted"), command,
                         sorted(skipped.items()), merged)


def main(argv=None) -> int:
    from episcatter.cmd_frontier import parse_size

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fit", nargs="+", default=FIT_RUNS)
    p.add_argument("--fit-only", action="store_true")
    p.add_argument("--seeds", type=int, default=None,
                   help="held-out scenes (usable ones; default 24); with --merge, keep the "
                        "first this many from --first-seed on")
    p.add_argument("--first-seed", type=int, default=None, help="default 1000")
    p.add_argument("--kind", default=KIND,
                   help="experiments.random_scenes kind of the scenes, or user / mixed "
                        "(experiments.user_scenes)")
    p.add_argument("--methods", nargs="+", default=list(METHODS))
    p.add_argument("--size", default="128x96")
    p.add_argument("--repeats", type=int, default=3,
                   help="timed renders after a warm-up (medians) of the auto render, its "
                        "choice and the fastest swept settings meeting each budget")
    p.add_argument("--no-probe-accuracy", action="store_true",
                   help="skip the probe-estimate table (three full-image marches a scene)")
    p.add_argument("--reference-cache", default=None,
                   help="directory keeping the held-out references for later runs")
    p.add_argument("--quick", action="store_true", help="tiny smoke run")
    p.add_argument("--merge", nargs="+", default=None, metavar="DIR",
                   help="merge the results of these runs (their --out folders; a later one's "
                        "scene and method replace an earlier one's) into --out")
    p.add_argument("--march-steps", nargs="+", type=int, default=None, metavar="N",
                   help="the marcher's swept step counts (default 16 ... 1024)")
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    if args.merge:
        if not args.out:
            p.error("--merge needs --out, the folder the merged results go to.")
        print(merge_runs(args.merge, args.out, "python -m experiments.error_budget "
                         + " ".join(argv if argv is not None else os.sys.argv[1:]),
                         args.first_seed, args.seeds, args.methods))
        return 0
    args.seeds = 24 if args.seeds is None else args.seeds
    args.first_seed = 1000 if args.first_seed is None else args.first_seed
    fit = fit_constants(load_rows([f for f in args.fit if os.path.isfile(f)])) \
        if any(os.path.isfile(f) for f in args.fit) else None
    if args.fit_only:
        print(json.dumps(fit, indent=1))
        return 0
    size = parse_size("24x18" if args.quick else args.size)
    sweeps = {**SWEEPS, "raymarch": march_sweep(args.march_steps)} if args.march_steps \
        else SWEEPS
    n = 1 if args.quick else args.seeds
    repeats = 1 if args.quick else args.repeats
    out = args.out or os.path.join("results", NAME)
    os.makedirs(out, exist_ok=True)
    scenes, skipped = held_out_scenes(n, args.first_seed, size, args.kind,
                                      args.reference_cache)
    choices, sweep, probes = [], [], []
    command = "python -m experiments.error_budget " + " ".join(argv if argv is not None
                                                               else os.sys.argv[1:])
    for name, spec, ref in scenes:        # the files are rewritten after every scene
        c, s, pr = run_scene(name, spec.load(), ref, args.methods, repeats,
                             lambda m: print(m, flush=True), not args.no_probe_accuracy,
                             sweeps)
        choices += c
        sweep += s
        probes += pr
        release_memory()
        text = write_results(out, choices, sweep, fit, command.strip(), skipped,
                             {"seeds": [n for n, _, _ in scenes], "skipped": skipped,
                              "methods": args.methods, "size": list(size), "repeats": repeats,
                              "fit": args.fit, "fitted": fit,
                              "reference": exact_description(2048) + ", pixel centres",
                              "kind": args.kind,
                              "march_steps": [r["steps"] for r in sweeps["raymarch"]]}, probes)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
