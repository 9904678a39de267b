"""``quality="auto"`` on the suite's scenes: what each budget gets.

Per scene (suite stems or XML paths) and budget: the settings the rule
chose, the achieved scale-free relMSE against the exact marcher (2,048
steps, 12 bisections, pixel centres), its ratio to the budget, the time of
the whole render with its probe, and the method's defaults (error, warm
time) beside it.  A quick look at where a rule misses or overshoots; the
held-out evaluation is :mod:`experiments.error_budget`.

``python -m experiments.auto_suite [--method epipolar_tree] [--size 160x120]
[--budgets 1e-3 1e-4 1e-5] [--scenes ...] [--out DIR]`` writes ``runs.csv``,
``runs.json`` and ``table.md`` into ``results/auto_suite/<method>`` (or
``--out``).
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from . import common as c

NAME = "auto_suite"
SCENES = ["beam", "grove", "hall", "nave_offscreen", "nave_onscreen", "point_fog", "spot_room",
          "sun_ahead", "sun_behind", "sun_room", "terrain", "six_spots"]


def measure(method: str, scenes, size, budgets) -> list[dict]:
    import mitsuba as mi

    from episcatter.metrics import scale_free_relmse

    rows = []
    for name in scenes:
        scene = c.load(c.scene_file(name), c.resolution(*size))
        ref = np.array(mi.load_dict({"type": "raymarch", "visibility": "exact", "steps": 2048,
                                     "boundary_bisections": 12})
                       .render_layers(scene, spp=1)["full"])
        default = mi.load_dict({"type": method})
        default.render_layers(scene, spp=1)
        t0 = time.perf_counter()
        img = np.array(default.render_layers(scene, spp=1)["full"])
        default_s = time.perf_counter() - t0
        default_err = scale_free_relmse(img, ref)
        for budget in budgets:
            integ = mi.load_dict({"type": method, "quality": "auto", "error_budget": budget})
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                t0 = time.perf_counter()
                result = integ.render_layers(scene, spp=1)
                seconds = time.perf_counter() - t0
            err = scale_free_relmse(np.array(result["full"]), ref)
            rows.append({"scene": name, "budget": budget,
                         "settings": result.stats.get("auto_settings"),
                         "relmse": err, "over_budget": err / budget, "time_s": seconds,
                         "predicted": result.stats.get("auto_predicted_relmse"),
                         "warned": bool(result.stats.get("auto_over_budget")),
                         "default_relmse": default_err, "default_s": default_s})
            r = rows[-1]
            print(f"{name} {budget:g}: {r['settings']} relMSE {err:.2e} ({r['over_budget']:.2f}x"
                  f" the budget) in {seconds:.2f} s; defaults {default_err:.2e} in "
                  f"{default_s:.2f} s", flush=True)
    return rows


def report(rows, method, size) -> str:
    table = [[r["scene"], f"{r['budget']:g}", f"`{r['settings']}`", f"{r['relmse']:.2e}",
              f"{r['over_budget']:.2f}", "yes" if r["warned"] else "", f"{r['time_s']:.2f}",
              f"{r['default_relmse']:.2e}", f"{r['default_s']:.2f}"] for r in rows]
    within = sum(r["over_budget"] <= 2 for r in rows)
    return (f"# quality='auto' of `{method}` on the suite, {size[0]}x{size[1]}, pixel centres\n\n"
            f"Within 2x of the budget: {within} of {len(rows)}.  time = the render with its "
            "probe (warm kernels); defaults = the method's defaults, warm.\n\n"
            + c.markdown_table(["scene", "budget", "chosen", "relMSE", "/ budget", "warned",
                                "time [s]", "defaults relMSE", "defaults [s]"], table))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--method", default="epipolar_tree")
    p.add_argument("--size", default="160x120", metavar="WxH")
    p.add_argument("--budgets", type=float, nargs="+", default=[1e-3, 1e-4, 1e-5])
    p.add_argument("--scenes", nargs="+", default=SCENES)
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    size = tuple(int(x) for x in args.size.split("x"))
    with c.limit_blas_threads(1):
        rows = measure(args.method, args.scenes, size, args.budgets)
    out = c.output_dir(NAME, args.out or str(c.RESULTS / NAME / args.method))
    text = report(rows, args.method, size)
    c.write_csv(out / "runs.csv", rows)
    c.write_json(out / "runs.json", {"name": NAME, "method": args.method, "size": size,
                                     "budgets": args.budgets, "scenes": args.scenes}, rows)
    c.write_text(out / "table.md", text)
    print(text)
    return rows


if __name__ == "__main__":
    main()
