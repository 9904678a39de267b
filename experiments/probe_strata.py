"""Which pixels should ``quality="auto"``'s probe measure on?  Per held-out
scene (``experiments.error_budget.scene_spec``, kind ``mixed``) and probe
setting of the three methods whose probe renders full images, the
setting's true relMSE (whole image, against the exact reference
``episcatter.reference.exact_props(2048)``) against estimates from 1,200
pixel centres measured against that same reference -- so only the choice
of pixels differs: 1,200 strided ones
(:func:`integrators.core.quality_auto.probe_pixels`), and stratified
samples (900 strided + 300 on the edges of the setting's image,
:class:`integrators.core.quality_auto.Strata`) on an edge stratum of 5 %
of the image (``share``) and on the probe's (at most
:data:`~integrators.core.quality_auto.EDGE_STRATUM` pixels, ``stratified``);
and the probe's own estimate (``probe``): its stratified sample against
its references (the budget 1e-4's, and on the edge stratum's pixels,
where the stratum is capped -- images larger than 320x240 --, the edge
reference, :meth:`~integrators.core.quality_auto.Probe.stratify`).

Writes ``results/probe_strata/``: ``runs.csv``, ``table.md``.
``python -m experiments.probe_strata [--size 320x240] [--seeds 2000,...]
[--out DIR]`` (about 4 minutes on 2 cores for the default 20 scenes at
320x240, 25 at 640x480).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

NAME = "probe_strata"
OUT = Path(__file__).resolve().parent.parent / "results" / NAME
#: the first 20 usable held-out scenes of the error-budget runs
SEEDS = (2000, 2001, 2003, 2004, 2005, 2006, 2007, 2008, 2009, 2010, 2011, 2012, 2013, 2014,
         2015, 2016, 2017, 2019, 2020, 2021)
#: the estimates compared (``runs.csv`` columns) and their names in the table
ESTIMATES = (("strided", "1,200 strided"),
             ("share", "900 strided + 300 edges, stratum 5 % of the image"),
             ("stratified", "900 strided + 300 edges, the probe's stratum"),
             ("probe", "the probe's stratum against its references"))
#: (method, settings): the probe settings of the tree, the filter and minmax
SETTINGS = (("epipolar_tree", {"slice_spacing": 2.0, "light_rays": 200}),
            ("epipolar_tree", {"slice_spacing": 2.0, "light_rays": 800}),
            ("fourier_filter", {}),
            ("minmax_epipolar", {"initial_step": 16}),
            ("minmax_epipolar", {"initial_step": 4}))


def run(seeds, width: int, height: int) -> list[dict]:
    import mitsuba as mi

    from episcatter import frontier as fr
    from episcatter.reference import exact_props, render_rgb
    from experiments.error_budget import scene_spec
    from integrators.core import quality_auto as qa

    from tqdm.auto import tqdm

    rows = []
    for seed in tqdm(seeds, desc="held-out scenes", unit="scene"):
        scene = scene_spec(seed, "mixed").at_resolution(width, height).load()
        ref = render_rgb(scene, mi.load_dict({"type": "raymarch", **exact_props(2048)}), spp=1)
        flat_ref = ref.reshape(-1, ref.shape[-1])
        strided = qa.probe_pixels(width, height)
        base = qa.probe_pixels(width, height, qa.PROBE_PIXELS - qa.EDGE_PIXELS)
        marched = {}
        for method, settings in SETTINGS:
            img = render_rgb(scene, mi.load_dict({"type": method, **settings}), spp=1)
            flat = img.reshape(-1, img.shape[-1])
            true = fr.image_errors(img, ref)["relmse"]
            row = {"seed": seed, "method": method, "settings": json.dumps(settings),
                   "true_relmse": true,
                   "strided": qa.subset_relmse(flat[strided], flat_ref[strided])}
            for key, most in (("share", None), ("stratified", qa.EDGE_STRATUM)):
                st = qa.Strata(base, qa.edge_pixels(img, most=most), width * height,
                               qa.EDGE_PIXELS)
                row[key] = qa.subset_relmse(flat[st.pixels], flat_ref[st.pixels],
                                            weights=st.weights)
            row["probe"] = probe_estimate(scene, img, st, marched)
            rows.append(row)
        del scene
    return rows


def probe_estimate(scene, img, strata, marched: dict) -> float:
    """The probe's estimate of ``img``'s relMSE on the stratified sample
    ``strata``: against the budget 1e-4's reference, on its edge
    stratum's pixels against the edge reference where the stratum is
    capped (:meth:`~integrators.core.quality_auto.Probe.stratify`;
    ``marched``: full images of those references, made once per scene)."""
    import mitsuba as mi

    from episcatter.reference import render_rgb
    from integrators.core import quality_auto as qa

    for key, edges in (("rest", False), ("edges", True)):
        if key not in marched:
            props = qa.reference_settings(scene, edges=edges)
            full = render_rgb(scene, mi.load_dict({"type": "raymarch", "visibility": "exact",
                                                   **props}), spp=1)
            marched[key] = full.reshape(-1, full.shape[-1])
    px = strata.pixels
    edge = strata.edge[:, None] & qa.edge_stratum_capped(img.shape[0] * img.shape[1])
    ref = np.where(edge, marched["edges"][px], marched["rest"][px])
    return qa.subset_relmse(img.reshape(-1, img.shape[-1])[px], ref, weights=strata.weights)


def summary(rows) -> dict:
    """Per estimate: median and 90th percentile of |log2(estimate / true)|,
    and how many estimates are under half / over twice the truth."""
    out = {}
    for key, _ in ESTIMATES:
        r = np.array([max(x[key], 1e-30) / x["true_relmse"] for x in rows
                      if x["true_relmse"] > 0])
        err = np.abs(np.log2(r))
        out[key] = {"cases": len(r), "median_abs_log2": float(np.median(err)),
                    "p90_abs_log2": float(np.percentile(err, 90)),
                    "under_half": int(np.sum(r < 0.5)), "over_twice": int(np.sum(r > 2))}
    return out


def table(rows, width: int, height: int) -> str:
    s = summary(rows)
    lines = [f"# Probe pixels at {width}x{height}", "",
             "Estimates of each probe setting's relMSE from 1,200 pixel centres against the "
             "exact reference (2,048 steps; the last row: against the probe's references), "
             "against the whole image's relMSE:", "",
             "| pixels | cases | median abs log2(est/true) | 90th pct | under half the truth | "
             "over twice |", "|---|---|---|---|---|---|"]
    for key, name in ESTIMATES:
        v = s[key]
        lines.append(f"| {name} | {v['cases']} | {v['median_abs_log2']:.2f} | "
                     f"{v['p90_abs_log2']:.2f} | {v['under_half']} | {v['over_twice']} |")
    lines += ["", "Per case (estimate / true):", "",
              "| seed | method | settings | true relMSE | "
              + " | ".join(k for k, _ in ESTIMATES) + " |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        t = r["true_relmse"]
        ratio = (lambda e: f"{e / t:.2f}" if t > 0 else "-")
        lines.append(f"| {r['seed']} | {r['method']} | {r['settings']} | {t:.2e} | "
                     + " | ".join(ratio(r[k]) for k, _ in ESTIMATES) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    from . import common as c

    rows, out = c.held_out_main(__doc__, SEEDS, OUT, run, table, argv)
    print((out / "table.md").read_text().split("\n\nPer case")[0])
    print(f"wrote {out}")
    return 0 if all(math.isfinite(r["probe"]) for r in rows) else 1


if __name__ == "__main__":
    main()
