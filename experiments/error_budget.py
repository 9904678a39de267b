"""The error-budget prototype held out (issue 16):
``python -m experiments.error_budget [--fit results/frontier/quick/runs.json]
[--size WxH] [--scenes stem:name=value,...] [--quick]``.

1. Fits each :data:`episcatter.frontier.BUDGET_RULES` exponent on the
   frontier runs of the suite (``--fit``; pixel-centre convention).
2. On scenes the fit did not see (``--scenes``: suite files with other media
   and surfaces through ``-D`` defines, or generated ones), for each method
   and budget 1e-3 / 1e-4 / 1e-5: :func:`episcatter.frontier.settings_for_budget`
   picks a setting, which is rendered (warm-up + median of ``repeats``) and
   compared with the exact pixel-centre reference; a sweep of the same knob
   on the same scene gives the frontier the choice is judged against
   (time of the fastest frontier setting meeting the achieved error).

Writes ``results/error_budget/``: ``choices.csv``, ``sweep.csv``,
``budget.json`` and ``table.md``.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import time

NAME = "error_budget"
#: held-out variants of the suite: other media (sigma_t, albedo) and lit surfaces
HELD_OUT = ["nave_offscreen_lit:sigma_t=0.1", "point_fog:sigma_t=0.1",
            "spot_room_lit:sigma_t=0.2", "beam_lit:sigma_t=0.03",
            "nave_onscreen:sigma_t=0.02"]
#: the knob values swept on each held-out scene (the frontier the choice is judged on)
SWEEPS = {"epipolar_tree": [0.25, 0.5, 1.0, 2.0, 4.0],
          "raymarch": [32, 64, 128, 256, 512, 1024],
          "fourier_filter": [8, 16, 32, 64, 128, 256]}
FITS = {"epipolar_tree": {"slice_interpolation": True, "light_rays": 0, "prefilter": 4},
        "raymarch": {"visibility": "exact"}, "fourier_filter": {"weights": "exact"}}


def parse_scene(text: str):
    """'stem:a=1,b=2' -> (stem, {'a': '1', 'b': '2'})."""
    stem, _, rest = text.partition(":")
    defines = dict(item.split("=", 1) for item in rest.split(",") if item)
    return stem, defines


def timed(scene, integrator, repeats):
    from episcatter.reference import render_rgb

    render_rgb(scene, integrator, spp=1)
    times, img = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        img = render_rgb(scene, integrator, spp=1)
        times.append(time.perf_counter() - t0)
    return img, statistics.median(times)


def fitted_rules(fit_path):
    """BUDGET_RULES with exponents fitted on the rows of a frontier runs.json
    (the default exponents where the file has too few runs)."""
    from episcatter import frontier as fr

    rules, fits = dict(fr.BUDGET_RULES), {}
    if fit_path and os.path.isfile(fit_path):
        with open(fit_path) as f:
            rows = json.load(f)["rows"]
        for method, rule in rules.items():
            try:
                k = fr.fit_exponent(rows, method, rule.knob, FITS.get(method))
            except ValueError:
                continue
            fits[method] = k
            rules[method] = fr.BudgetRule(rule.knob, rule.coarse, rule.fine, k, rule.limits,
                                          rule.base, rule.integer, rule.safety)
    return rules, fits


def main(argv=None) -> int:
    import scenes as suite

    from episcatter import frontier as fr
    from episcatter.cmd_frontier import parse_size
    from episcatter.frontier_report import environment, write_rows_csv
    from episcatter.reference import load_reference
    from episcatter.scene_loading import load_scene, make_integrator

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fit", default="results/frontier/quick/runs.json")
    p.add_argument("--scenes", nargs="+", default=HELD_OUT)
    p.add_argument("--methods", nargs="+", default=["epipolar_tree", "raymarch"])
    p.add_argument("--size", default="160x120")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--quick", action="store_true", help="tiny smoke run")
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    w, h = parse_size("32x24" if args.quick else args.size)
    scenes_ = args.scenes[:1] if args.quick else args.scenes
    repeats = 1 if args.quick else args.repeats
    out = args.out or os.path.join("results", NAME, "quick" if args.quick else "")
    os.makedirs(out, exist_ok=True)
    rules, fits = fitted_rules(args.fit)
    choices, sweep = [], []
    for text in scenes_:
        stem, extra = parse_scene(text)
        path = suite.path(stem)
        defines = {**extra, "res_x": str(w), "res_y": str(h)}
        ref, _ = load_reference(fr.make_reference(path, defines, "pixel_centre",
                                                  progress=not args.quick))
        scene = load_scene(path, defines)
        for method in args.methods:
            rule = rules[method]
            pts = []
            for v in SWEEPS[method]:
                img, t = timed(scene, make_integrator(method, rule.settings(v)), repeats)
                e = fr.image_errors(img, ref)["relmse"]
                pts.append((t, e))
                sweep.append({"scene": text, "method": method, rule.knob: v, "time_s": t,
                              "relmse": e})
            front = fr.pareto_front(pts)
            for budget in fr.LEVELS:
                t0 = time.perf_counter()
                probe = fr.budget_probe(scene, method, rule)
                settings = rule.choose(probe["probe_relmse"], budget)
                choose_s = time.perf_counter() - t0
                img, t = timed(scene, make_integrator(method, settings), repeats)
                err = fr.image_errors(img, ref)
                best_t, best_bound = fr.time_at_error(front, err["relmse"]) if err["relmse"] > 0 \
                    else (float("nan"), "?")
                choices.append({"scene": text, "method": method, "budget": budget,
                                "settings": settings, "probe_relmse": probe["probe_relmse"],
                                "probe_s": choose_s, "time_s": t, **err,
                                "error_over_budget": err["relmse"] / budget,
                                "frontier_time_at_error_s": best_t,
                                "frontier_bound": best_bound,
                                "time_over_frontier": t / best_t if best_t else float("nan"),
                                "time_with_probe_over_frontier":
                                    (t + choose_s) / best_t if best_t else float("nan")})
                print(f"{text} {method} budget {budget:g}: {settings} relMSE "
                      f"{err['relmse']:.3g} ({err['relmse'] / budget:.2f}x) time {t:.3g} s "
                      f"(frontier {best_bound} {best_t:.3g} s)", flush=True)
    write_rows_csv(os.path.join(out, "choices.csv"), choices)
    write_rows_csv(os.path.join(out, "sweep.csv"), sweep)
    summary = summarize(choices)
    with open(os.path.join(out, "budget.json"), "w") as f:
        json.dump({"settings": {"scenes": scenes_, "methods": args.methods, "size": [w, h],
                                "repeats": repeats, "fit": args.fit, "fitted_exponents": fits,
                                "reference": "raymarch visibility=exact steps=2048, pixel centres"},
                   "environment": environment(), "summary": summary}, f, indent=1, default=str)
    with open(os.path.join(out, "table.md"), "w") as f:
        f.write(report(choices, summary, fits))
    print(report(choices, summary, fits))
    return 0


def summarize(choices) -> dict:
    """Share of cases within 2x of the budget (<= 2x, and in [0.5, 2]) and
    within 2x of the frontier's time at the achieved error, per method."""
    out = {}
    for method in sorted({c["method"] for c in choices}):
        sel = [c for c in choices if c["method"] == method]
        n = len(sel)
        out[method] = {
            "cases": n,
            "error_le_2x_budget": sum(c["error_over_budget"] <= 2 for c in sel) / n,
            "error_within_2x_either_way": sum(0.5 <= c["error_over_budget"] <= 2 for c in sel) / n,
            "time_le_2x_frontier": sum(c["time_over_frontier"] <= 2 for c in sel) / n,
            "time_with_probe_le_2x_frontier":
                sum(c["time_with_probe_over_frontier"] <= 2 for c in sel) / n}
    return out


def report(choices, summary, fits) -> str:
    lines = ["| scene | method | budget | setting | relMSE | / budget | time [s] | "
             "frontier time at that error [s] | time / frontier (with probe) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for c in choices:
        knob = {k: v for k, v in c["settings"].items() if k != "visibility" and k != "weights"}
        lines.append(f"| {c['scene']} | {c['method']} | {c['budget']:g} | {knob} | "
                     f"{c['relmse']:.3g} | {c['error_over_budget']:.2f} | {c['time_s']:.3g} | "
                     f"{'' if c['frontier_bound'] == '=' else c['frontier_bound'] + ' '}"
                     f"{c['frontier_time_at_error_s']:.3g} | {c['time_over_frontier']:.2f} "
                     f"({c['time_with_probe_over_frontier']:.2f}) |")
    lines += ["", f"fitted exponents: {fits}", "", "| method | cases | relMSE <= 2x budget | "
              "in [budget/2, 2 budget] | time <= 2x frontier | same with probe |",
              "|---|---|---|---|---|---|"]
    for m, s in summary.items():
        lines.append(f"| {m} | {s['cases']} | {s['error_le_2x_budget']:.0%} | "
                     f"{s['error_within_2x_either_way']:.0%} | {s['time_le_2x_frontier']:.0%} | "
                     f"{s['time_with_probe_le_2x_frontier']:.0%} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
