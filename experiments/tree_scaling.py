"""How ``epipolar_tree`` and ray marching scale with resolution (issue point 4).

Mirrors Baran et al. 2010, Fig. 12 (TREES scene, CPU): time against
``(s·r·d)^(1/3)`` on log-log axes, where ``s`` = epipolar slices, ``r`` =
view rays per slice and ``d`` = light rays per slice (the tree) or samples
per view ray (the ray marcher).  The paper fits slopes of 1.94 (tree,
"essentially quadratic") and 2.83 (brute force, "roughly cubic").

Here the image goes from 160x120 to k times that (k = 1 ... 16, up to
2560x1920) on the grove (our TREES) and both "depth" resolutions grow with
it:

- ``epipolar_tree``: ``slices`` automatic (Baran's sinh distribution, §8:
  ∝ image size; ``s`` from :func:`rectify.describe.describe`), ``light_rays``
  ``d`` = the image diagonal in pixels (its automatic value, set explicitly);
  every pixel is a query of its slice, so ``s·r`` = the pixels and
  ``x = (pixels·d)^(1/3)``;
- ``raymarch`` (shadow-map visibility, fixed 2048² map): ``steps`` = 64·k,
  ``x = (pixels·steps)^(1/3)``.

Times: median of 5 warm runs, in rounds interleaved over every size and
method, in one process (sizes measured one after the other picked up load
changes of the shared machine as fake slope changes); the tree's whole
scattering stage (rectify + blockers + svd + sweep + unrectify + ring) and
the ray marcher's march alone (shadow-map build excluded: it does not grow
with the image; the paper's brute force also excluded map construction).
Slopes are least-squares fits of log(time) on log(x), over all sizes and
over the largest three (fixed per-frame overheads flatten the small end);
the tree's stages are fitted too.

Writes ``results/tree_scaling/``: ``scaling.csv``, ``slopes.csv``,
``scaling.json``, ``table.md``, ``scaling.png``.
``python -m experiments.tree_scaling [--quick] [--scenes grove]``.
"""
from __future__ import annotations

import sys

import math

import numpy as np

from . import common as c

NAME = "tree_scaling"
PAPER_SLOPES = {"epipolar_tree": 1.94, "raymarch": 2.83}
TREE_STAGES = ("rectify", "blockers", "svd", "sweep", "unrectify", "ring")


def settings_for(quick: bool) -> dict:
    """Base size, scale factors, steps per factor, shadow-map size."""
    if quick:
        return {"base": (32, 24), "factors": [1, 2, 3], "steps_per_factor": 8,
                "shadowmap_resolution": 256}
    return {"base": (160, 120), "factors": [1, 2, 4, 8, 12, 16], "steps_per_factor": 64,
            "shadowmap_resolution": 2048}


def slice_count(path: str, defines: dict) -> int:
    """Baran's sinh slice count of the scene at this resolution (what the
    tree's automatic ``slices`` uses)."""
    from episcatter.cmd_epipolar import scene_geometry

    return int(scene_geometry(path, defines)["slices_sinh"])


def size_setting(path: str, k: int, s: dict) -> dict:
    """Image size, d / steps and the loaded scene at scale factor ``k``."""
    w, h = s["base"][0] * k, s["base"][1] * k
    defines = c.resolution(w, h)
    return {"factor": k, "width": w, "height": h, "pixels": w * h,
            "d": max(32, math.ceil(math.hypot(w, h))), "steps": s["steps_per_factor"] * k,
            "slices": slice_count(path, defines), "scene": c.load(path, defines)}


def jobs_of(size: dict, s: dict) -> dict:
    """(method, factor) -> (scene, integrator) at one size."""
    tree = c.build("epipolar_tree", {"light_rays": size["d"]})
    march = c.build("raymarch", {"steps": size["steps"], "visibility": "shadowmap",
                                 "shadowmap_resolution": s["shadowmap_resolution"]})
    return {("epipolar_tree", size["factor"]): (size["scene"], tree),
            ("raymarch", size["factor"]): (size["scene"], march)}


def row_of(method: str, size: dict, t: dict, loads: list) -> dict:
    """One measured (method, size) as a flat row."""
    tree = method == "epipolar_tree"
    depth = size["d"] if tree else size["steps"]
    row = {"method": method, **{k: size[k] for k in ("factor", "width", "height", "pixels")},
           "slices": size["slices"] if tree else None,
           "rays_per_slice": size["pixels"] / size["slices"] if tree else None,
           "depth_samples": depth, "x": (size["pixels"] * depth) ** (1 / 3),
           "status": t.get("error", "ok"), "load_before": loads[0], "load_after": loads[1]}
    if "error" not in t:
        row.update({k: t[k] for k in ("time_s", "time_min_s", "time_max_s", "scattering_s",
                                      "scattering_net_s", "first_run_s", "stages")})
        row["fit_time_s"] = t["scattering_s"] if tree else t["scattering_net_s"]
    return row


def measure(path: str, s: dict, repeats: int, progress: bool) -> list[dict]:
    """Every size and method, timed in interleaved rounds over *all* of
    them (a load change on the shared machine then cannot bend the slope)."""
    sizes = [size_setting(path, k, s) for k in s["factors"]]
    jobs = {}
    for size in sizes:
        jobs.update(jobs_of(size, s))
    before = c.load_average()
    timed = c.time_jobs(jobs, repeats=repeats, progress=progress)
    loads = [before, c.load_average()]
    return [row_of(method, size, timed[(method, size["factor"])], loads)
            for size in sizes for method in ("epipolar_tree", "raymarch")]


def slope(x, y) -> float:
    """Least-squares slope of log y on log x (NaN with < 2 usable points)."""
    pts = [(a, b) for a, b in zip(x, y) if a and b and a > 0 and b > 0]
    if len(pts) < 2:
        return math.nan
    lx, ly = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(lx, ly, 1)[0])


def fit_slopes(rows: list[dict]) -> list[dict]:
    """Slopes of each method's fitted time (and of the tree's stages, the
    end-to-end time) over all sizes and over the largest three; stages
    that stay below 1 ms are left out."""
    out = []
    for method in ("epipolar_tree", "raymarch"):
        mine = sorted((r for r in rows if r["method"] == method and r["status"] == "ok"),
                      key=lambda r: r["x"])
        series = {"fitted time": [r["fit_time_s"] for r in mine],
                  "end-to-end": [r["time_s"] for r in mine]}
        if method == "epipolar_tree":
            series.update({f"stage {k}": [r["stages"].get(k) for r in mine]
                           for k in TREE_STAGES})
        x = [r["x"] for r in mine]
        for what, y in series.items():
            if what.startswith("stage") and max((v or 0.0) for v in y) < 1e-3:
                continue        # e.g. an empty ring: nothing to fit
            out.append({"method": method, "series": what, "slope_all": slope(x, y),
                        "slope_top3": slope(x[-3:], y[-3:]), "points": len(x),
                        "paper": PAPER_SLOPES[method] if what == "fitted time" else None})
    return out


def plot(path, rows, slopes, scene: str) -> None:
    """Fig. 12: log-log time vs (s·r·d)^(1/3), fitted slopes in the legend."""
    plt = c.pyplot()
    fig, ax = plt.subplots(figsize=(5.2, 3.8))
    for method, marker in (("epipolar_tree", "o"), ("raymarch", "s")):
        mine = sorted((r for r in rows if r["method"] == method and r["status"] == "ok"),
                      key=lambda r: r["x"])
        fit = next(s for s in slopes if s["method"] == method and s["series"] == "fitted time")
        ax.plot([r["x"] for r in mine], [r["fit_time_s"] for r in mine], marker + "-",
                label=f"{method}: slope {fit['slope_all']:.2f} (top 3: {fit['slope_top3']:.2f}; "
                      f"paper {PAPER_SLOPES[method]})")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("(s·r·d)^(1/3)")
    ax.set_ylabel("scattering time [s] (median)")
    ax.set_title(f"tree_scaling on {scene} (Baran Fig. 12)", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    c.savefig(fig, path)


def report(rows, slopes, s, repeats, scene) -> str:
    header = ["method", "image", "s", "r", "d / steps", "x=(srd)^(1/3)", "fitted [ms]",
              "total [ms]", "status"]
    body = [[r["method"], f"{r['width']}x{r['height']}", c.fmt(r["slices"]),
             c.fmt(r["rays_per_slice"], 4), r["depth_samples"], c.fmt(r["x"], 4),
             c.fmt(1000 * r["fit_time_s"], 4) if "fit_time_s" in r else "-",
             c.fmt(1000 * r["time_s"], 4) if "time_s" in r else "-",
             "ok" if r["status"] == "ok" else r["status"][:80]] for r in rows]
    sl = [[x["method"], x["series"], c.fmt(x["slope_all"]), c.fmt(x["slope_top3"]),
           c.fmt(x["paper"])] for x in slopes]
    loads = [r["load_before"] for r in rows] + [r["load_after"] for r in rows]
    return "\n\n".join([
        f"# tree_scaling on {scene} (Baran 2010 Fig. 12)",
        f"Median of {repeats} warm runs, rounds interleaved over all sizes and methods, "
        f"{c.environment()['drjit_threads']} "
        f"threads; load average (1/5/15 min) first {loads[0]}, max 1-min "
        f"{max(l[0] for l in loads)}. Fitted time: the tree's scattering stage; raymarch's "
        f"march alone (shadow map {s['shadowmap_resolution']}² build excluded).",
        c.markdown_table(header, body),
        "## Log-log slopes of time against (s·r·d)^(1/3)",
        c.markdown_table(["method", "series", "slope (all sizes)", "slope (largest 3)",
                          "paper"], sl)])


def main(argv=None):
    run = c.start_run(sys.modules[__name__], argv, ["grove"], ["nave_offscreen"],
                      default_repeats=5)
    args, s, repeats, out = run.args, run.settings, run.repeats, run.out
    scene = run.scenes[0]
    path = c.scene_file(scene)
    rows = measure(path, s, repeats, progress=not args.quick)
    slopes = fit_slopes(rows)
    text = report(rows, slopes, s, repeats, scene)
    print(text)
    settings = {"name": NAME, "scene": scene, **s, "repeats": repeats, "quick": args.quick,
                "x": "(pixels * d)^(1/3): s*r = pixels (every pixel is a query of its slice)",
                "fitted_time": {"epipolar_tree": "scattering stage",
                                "raymarch": "scattering minus shadow-map build"}}
    c.write_csv(out / "scaling.csv", rows)
    c.write_csv(out / "slopes.csv", slopes)
    c.write_json(out / "scaling.json", settings, rows, slopes=slopes)
    c.write_text(out / "table.md", text)
    plot(out / "scaling.png", rows, slopes, scene)
    return rows, slopes


if __name__ == "__main__":
    main()
