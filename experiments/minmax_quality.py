"""Where epipolar interpolation can fail (issue 14, point 4): the grove
(many depth breaks) and the beam (a tight beam on a flat floor, no depth
break at its edges; Baran 2010 Fig. 13), for each refinement criterion of
``minmax_epipolar`` (``depth`` = the talk, ``inscattering``, ``visibility``)
next to ``epipolar_tree`` (every camera sample evaluated at its own depth).

Per scene and method, at pixel centres against the exact working reference
(``raymarch visibility=exact``): integration samples and fix-up pixels
(minmax), the whole-image errors (scale-free relMSE, mean ratio, max error
/ peak, FLIP) and the errors on two pixel sets:

* ``depth edges``: pixels whose camera depth differs from a 4-neighbour's
  by more than 10 % (and their 4-neighbours);
* ``shaft edges``: pixels where the reference changes by more than 20 % of
  the local maximum toward a 4-neighbour, in light above 5 % of the peak
  (the beam's and the shafts' borders), dilated by one pixel;

on each set the scale-free relMSE (ε from the whole image's mean, DESIGN
§2) and the mean |error| / peak.  ``error_maps.png``: |error| / peak per
method.

Writes ``results/minmax_quality/``: ``runs.csv``, ``runs.json``,
``table.md``, ``error_maps.png``.
``python -m experiments.minmax_quality [--quick]``.
"""
from __future__ import annotations

import numpy as np

from episcatter import metrics

from . import common as c
from . import minmax_common as mc

NAME = "minmax_quality"
SCENES = ["grove", "beam"]
QUICK_SCENES = ["beam"]
METHODS = {
    # the epipolar pipeline at every size (--quick's small images would march every pixel)
    "minmax depth": ("minmax_epipolar", {"refinement": "depth", "small_image_march": False}),
    "minmax inscattering": ("minmax_epipolar", {"refinement": "inscattering",
                                                "small_image_march": False}),
    "minmax visibility": ("minmax_epipolar", {"refinement": "visibility",
                                              "small_image_march": False}),
    "epipolar_tree": ("epipolar_tree", {}),
}


def settings_for(quick: bool) -> dict:
    if quick:
        return {"width": 48, "height": 36, "reference_steps": 64}
    return {"width": 320, "height": 240, "reference_steps": 1024}


def shift_max(a):
    """Max over the 4-neighbours (edges replicate)."""
    p = np.pad(a, 1, mode="edge")
    return np.maximum.reduce([p[:-2, 1:-1], p[2:, 1:-1], p[1:-1, :-2], p[1:-1, 2:]])


def dilate(mask):
    return mask | shift_max(mask.astype(np.uint8)).astype(bool)


def depth_edges(depth):
    d = np.where(np.isfinite(depth), depth, 1e30)
    p = np.pad(d, 1, mode="edge")
    rel = np.zeros(d.shape)
    for nb in (p[:-2, 1:-1], p[2:, 1:-1], p[1:-1, :-2], p[1:-1, 2:]):
        rel = np.maximum(rel, np.abs(nb - d) / np.maximum(np.minimum(nb, d), 1e-12))
    return dilate(rel > 0.1)


def shaft_edges(ref):
    y = ref.mean(axis=-1)
    local = shift_max(y)
    p = np.pad(y, 1, mode="edge")
    jump = np.zeros(y.shape)
    for nb in (p[:-2, 1:-1], p[2:, 1:-1], p[1:-1, :-2], p[1:-1, 2:]):
        jump = np.maximum(jump, np.abs(nb - y))
    return dilate((jump > 0.2 * np.maximum(local, y)) & (np.maximum(local, y) > 0.05 * y.max()))


def masked_errors(img, ref, mask) -> dict:
    if not mask.any():
        return {"relmse": float("nan"), "mean_abs_over_peak": float("nan"), "pixels": 0}
    eps = metrics.DEFAULT_EPS * float(np.mean(ref)) ** 2
    x, y = img[mask], ref[mask]
    return {"relmse": float(np.mean((x - y) ** 2 / (y ** 2 + eps))),
            "mean_abs_over_peak": float(np.mean(np.abs(x - y)) / max(ref.max(), 1e-30)),
            "pixels": int(mask.sum())}


def render_with_counts(integ, scene):
    """(full image (H, W, 3) float64, counts) of one 1-spp render; counts:
    ``integration_samples``, ``used_samples`` and ``fixup_pixels`` from the
    render's ``RenderResult.stats`` (``minmax_epipolar``; empty otherwise)."""
    result = integ.render_layers(scene, 0, 0, 1)
    img = np.asarray(result["full"], np.float64)[..., :3]
    keys = ("integration_samples", "used_samples", "fixup_pixels")
    return img, {k: result.stats[k] for k in keys if k in result.stats}


def measure_scene(name, s, progress):
    path = c.scene_file(name)
    defines = {**c.resolution(s["width"], s["height"])}
    ref, _ = c.exact_reference(path, defines, s["reference_steps"], progress=progress)
    ref = np.asarray(ref, np.float64)
    scene = c.load(path, defines)
    layers = c.build("raymarch", {"steps": 1}).render_layers(scene, spp=1)
    depth = np.asarray(layers["distance"], np.float64)[..., 0]
    masks = {"depth edges": depth_edges(depth), "shaft edges": shaft_edges(ref)}
    rows, images = [], {}
    for label, (kind, props) in METHODS.items():
        img, counts = render_with_counts(c.build(kind, {**props, "output": "full"}), scene)
        images[label] = img
        row = {"scene": name, "method": label, **mc.quality(img, ref), **counts}
        for mname, m in masks.items():
            e = masked_errors(img, ref, m)
            row.update({f"{mname} relmse": e["relmse"],
                        f"{mname} mean_abs/peak": e["mean_abs_over_peak"],
                        f"{mname} pixels": e["pixels"]})
        rows.append(row)
    return rows, images, ref


def plot(path, panels):
    plt = c.pyplot()
    n = max(len(v[0]) for v in panels.values())
    fig, axes = plt.subplots(len(panels), n + 1, figsize=(2.6 * (n + 1), 2.2 * len(panels)),
                             squeeze=False)
    for row, (name, (images, ref)) in zip(axes, panels.items()):
        peak = max(ref.max(), 1e-30)
        row[0].imshow(np.clip(ref / peak, 0, 1) ** (1 / 2.2))
        row[0].set_title(f"{name}: reference", fontsize=7)
        for ax, (label, img) in zip(row[1:], images.items()):
            ax.imshow(np.abs(img - ref).mean(-1) / peak, cmap="magma", vmin=0, vmax=0.1)
            ax.set_title(f"|error|/peak: {label}", fontsize=7)
        for ax in row:
            ax.axis("off")
    c.savefig(fig, path)


def report(rows, s) -> str:
    header = ["scene", "method", "integration samples", "fix-up px", "relMSE", "mean ratio",
              "max err/peak", "FLIP", "depth-edge relMSE", "depth-edge mean|e|/peak",
              "shaft-edge relMSE", "shaft-edge mean|e|/peak"]
    body = [[r["scene"], r["method"], r.get("integration_samples", "-"),
             r.get("fixup_pixels", "-"), c.fmt(r["relmse"]), c.fmt(r["mean_ratio"], 4),
             c.fmt(r["max_err_over_peak"]), c.fmt(r["flip"]), c.fmt(r["depth edges relmse"]),
             c.fmt(r["depth edges mean_abs/peak"]), c.fmt(r["shaft edges relmse"]),
             c.fmt(r["shaft edges mean_abs/peak"])] for r in rows]
    return (c.markdown_table(header, body)
            + f"\n\nFull images (output=full), {s['width']}x{s['height']}, {mc.CONVENTION} "
              f"({s['reference_steps']} steps); scale-free relMSE. Defaults otherwise.\n")


def main(argv=None):
    run = c.start_run(__import__(__name__, fromlist=["x"]), argv, SCENES, QUICK_SCENES)
    rows, panels = [], {}
    for name in run.scenes:
        r, images, ref = measure_scene(name, run.settings, not run.args.quick)
        rows += r
        panels[name] = (images, ref)
        print(f"{name}: done (load {c.load_average()})", flush=True)
    text = report(rows, run.settings)
    print(text)
    mc.write_results(run.out, {"name": NAME, **run.settings, "scenes": run.scenes,
                               "quick": run.args.quick}, rows, text)
    plot(run.out / "error_maps.png", panels)
    return rows


if __name__ == "__main__":
    main()
