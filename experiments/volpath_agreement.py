"""``raymarch visibility=exact`` against the shipped volpath references
(foundation issue; antialiased convention).

For each case of :data:`experiments.make_shipped_references.AGREEMENT`
(48x36, 65,536-spp volpath ``max_depth=2`` images in ``references/``):
``raymarch visibility=exact steps=256`` with 16x16 stratified jittered
camera samples per pixel and a jittered step offset per ray, so both sides
integrate the pixel footprint.  Reports the mean ratio, the scale-free
relMSE after 4x4 block averaging (DESIGN §2), the reference's own noise at
that block size (from its 64 chunk means) and their ratio.  Criteria:
mean within 1 %, relMSE <= 2x the reference noise
(``tests/test_volpath_agreement.py`` asserts them).

``python -m experiments.volpath_agreement`` writes
``results/volpath_agreement/`` (table.md, rows.csv, rows.json).
"""
from __future__ import annotations

import argparse

import numpy as np

from experiments import common as c
from experiments.make_shipped_references import AGREEMENT

BLOCK = 4
SETTINGS = {"type": "raymarch", "visibility": "exact", "steps": 256,
            "samples_per_pixel": 256, "jitter": True}


def agreement(stem: str, defines: dict) -> dict:
    """Mean ratio, block relMSE and reference noise of one shipped case."""
    import mitsuba as mi

    import scenes
    from episcatter.metrics import block_average, noise_relmse_from_variance, scale_free_relmse
    from episcatter.reference import SHIPPED_DIR, find_cached_reference, load_reference, load_variance
    from episcatter.scene_loading import load_scene

    path = scenes.path(stem)
    ref_path = find_cached_reference(path, defines, cache_dir=SHIPPED_DIR)
    if not ref_path:
        raise FileNotFoundError(f"shipped reference of {stem} {defines} missing: run "
                                "`python -m experiments.make_shipped_references`")
    ref, _ = load_reference(ref_path)
    variance = load_variance(ref_path)
    scene = load_scene(path, defines)
    ours = np.array(mi.load_dict(SETTINGS).render_layers(scene)["full"])
    err = scale_free_relmse(block_average(ours, BLOCK), block_average(ref, BLOCK))
    noise = noise_relmse_from_variance(ref, variance, block=BLOCK)
    return {"scene": stem, "defines": defines, "mean_ratio": float(ours.mean() / ref.mean()),
            "relmse_block4": float(err), "reference_noise_block4": float(noise),
            "relmse_over_noise": float(err / noise)}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    with c.limit_blas_threads(1):
        rows = [agreement(stem, defines) for stem, defines, _ in AGREEMENT]
    out = c.output_dir("volpath_agreement", args.out)
    c.write_csv(out / "rows.csv", rows)
    c.write_json(out / "rows.json", {"integrator": SETTINGS, "block": BLOCK}, rows)
    table = c.markdown_table(
        ["scene (defines)", "mean ratio", "relMSE (4x4 blocks)", "reference noise", "ratio"],
        [[f"{r['scene']} {r['defines']}", f"{r['mean_ratio']:.4f}", f"{r['relmse_block4']:.2e}",
          f"{r['reference_noise_block4']:.2e}", f"{r['relmse_over_noise']:.2f}"] for r in rows])
    c.write_text(out / "table.md", "# raymarch exact vs volpath (antialiased, 48x36, "
                 "scale-free relMSE, eps = 1e-2 mean(ref)^2)\n\n" + table)
    print(table)


if __name__ == "__main__":
    main()
