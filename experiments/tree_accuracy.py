"""Accuracy of ``epipolar_tree`` on the scene suite (issue point 2).

Mirrors the quality side of Baran et al. 2010, Fig. 11 / §10.1 (their
method next to a shadow-mapped ray marcher), with numbers instead of
side-by-side images: every suite scene at 640x480, errors against the exact
working reference (``raymarch visibility=exact``, 2048 steps, 1 sample per
pixel at the pixel centre; :func:`experiments.common.exact_reference`):
relMSE (eps 1e-2) and HDR-FLIP (:func:`episcatter.metrics.compare`) at
block 1 and block 2, for

- ``epipolar_tree`` at its defaults,
- ``raymarch`` with shadow-map visibility (default 2048² map, 2×2 PCF) at
  256 and 1024 steps,
- ``fourier_filter`` at its defaults,

plus the median time of 3 warm runs (end-to-end and scattering-only).
A method that rejects a scene (e.g. a point or spot light it does not
support yet) is listed with its status instead of numbers.

Also per method: the share of pixels the reference renders exactly black
and the method's light on them (:func:`black_leak`), and for the tree and
raymarch 1024 a map of log10 |error| per scene (``error_maps.png``).

Writes ``results/tree_accuracy/``: ``accuracy.csv``, ``accuracy.json``,
``table.md``, ``accuracy.png``, ``error_maps.png``.  ``python -m experiments.tree_accuracy
[--quick] [--scenes ...]``.
"""
from __future__ import annotations

import sys

from . import common as c

NAME = "tree_accuracy"
SUITE = ["nave_offscreen", "nave_onscreen", "grove", "terrain", "spot_room", "point_fog", "beam"]
QUICK_SCENES = ["nave_offscreen"]
#: (label, integrator type, properties)
METHODS = [
    ("epipolar_tree", "epipolar_tree", {}),
    ("raymarch sm 256", "raymarch", {"visibility": "shadowmap", "steps": 256}),
    ("raymarch sm 1024", "raymarch", {"visibility": "shadowmap", "steps": 1024}),
    ("fourier_filter", "fourier_filter", {}),
]


def settings_for(quick: bool) -> dict:
    """Resolution and reference steps (``--quick``: 64x48, 256 steps)."""
    if quick:   # a 256² shadow map: building the 2048² one alone takes seconds
        return {"width": 64, "height": 48, "reference_steps": 256,
                "raymarch_extra": {"shadowmap_resolution": 256}}
    return {"width": 640, "height": 480, "reference_steps": c.REFERENCE_STEPS,
            "raymarch_extra": {}}


def method_params(kind: str, props: dict, s: dict) -> dict:
    """A method's properties with the run's raymarch overrides."""
    return {**props, **(s["raymarch_extra"] if kind == "raymarch" else {})}


#: methods whose per-pixel error maps go into ``error_maps.png``
MAPPED = ("epipolar_tree", "raymarch sm 1024")
#: block size of the error maps (max-free mean of |error| over k x k pixels)
MAP_BLOCK = 4


def black_leak(img, ref, threshold: float = 1e-4) -> dict:
    """Light where the reference is exactly black (all channels 0: fully
    shadowed and unlit): the fraction of such reference pixels, the test's
    largest value there and how many of them exceed ``threshold``; plus the
    largest |error| relative to the reference's peak.  HDR-FLIP sets its
    exposure range from the reference, so in mostly black references
    (``beam``) it amplifies even 1e-7 residues there; these numbers say
    whether a high FLIP is such a residue or a visible leak."""
    import numpy as np

    black = np.all(ref == 0, axis=-1)
    finite = np.where(np.isfinite(img), img, 0.0)
    leak = finite[black].max(axis=-1) if black.any() else np.zeros(0)
    peak = float(np.max(ref))
    return {"ref_black_frac": float(black.mean()),
            "leak_max": float(leak.max()) if leak.size else 0.0,
            "leak_px": int((leak > threshold).sum()),
            "max_err_rel_peak": float(np.max(np.abs(finite - ref))) / peak if peak > 0 else 0.0}


def error_map(img, ref):
    """log10 of the mean |error| (summed over channels) over MAP_BLOCK² blocks."""
    import numpy as np

    from episcatter.metrics import block_average

    err = np.abs(np.where(np.isfinite(img), img, 0.0) - ref).sum(axis=-1)
    return np.log10(block_average(err, MAP_BLOCK) + 1e-9)


def measure_scene(scene_name: str, s: dict, repeats: int, progress: bool,
                  maps: dict | None = None) -> list[dict]:
    """One row per method on one scene: errors at block 1 and 2, black-pixel
    leaks and times; ``maps`` (if given) receives the reference and the
    error maps of the MAPPED methods."""
    scene, ref, info = c.scene_with_reference(scene_name, s, progress)
    integs = {label: c.build(kind, method_params(kind, props, s))
              for label, kind, props in METHODS}
    load_before = c.load_average()
    timed = c.time_renders(scene, integs, repeats=repeats)
    rows = []
    for label, kind, props in METHODS:
        t = timed[label]
        row = {"scene": scene_name, "method": label, "integrator": kind,
               "params": method_params(kind, props, s),
               "width": s["width"], "height": s["height"],
               "status": t.get("error", "ok"), "reference": info["path"],
               "load_before": load_before, "load_after": c.load_average()}
        if "error" not in t:
            row.update(c.errors(t["image"], ref))
            row.update(black_leak(t["image"], ref))
            if maps is not None and label in MAPPED:
                maps.setdefault(scene_name, {"reference": ref})[label] = \
                    error_map(t["image"], ref)
            row.update({k: t[k] for k in ("time_s", "scattering_s", "scattering_net_s",
                                          "first_run_s", "stages")})
        rows.append(row)
    return rows


def table(rows: list[dict]) -> str:
    """The markdown table of every (scene, method)."""
    header = ["scene", "method", "relMSE b1", "FLIP b1", "relMSE b2", "FLIP b2",
              "max err / peak", "black ref px", "max there", "px > 1e-4 there",
              "total [ms]", "scattering [ms]", "status"]
    body = []
    for r in rows:
        ok = r["status"] == "ok"
        ms = (lambda k: c.fmt(1000 * r[k], 4)) if ok else (lambda k: "-")
        body.append([r["scene"], r["method"],
                     c.fmt(r.get("relmse_b1")), c.fmt(r.get("flip_b1")),
                     c.fmt(r.get("relmse_b2")), c.fmt(r.get("flip_b2")),
                     c.fmt(r.get("max_err_rel_peak")),
                     f"{100 * r['ref_black_frac']:.0f}%" if ok else "-",
                     c.fmt(r.get("leak_max")), c.fmt(r.get("leak_px")),
                     ms("time_s"), ms("scattering_s"),
                     "ok" if ok else r["status"][:90]])
    return c.markdown_table(header, body)


def plot(path, rows: list[dict]) -> None:
    """relMSE (block 1) per scene, one bar per method, log scale."""
    import numpy as np

    plt = c.pyplot()
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    methods = [m[0] for m in METHODS]
    fig, ax = plt.subplots(figsize=(7, 3.6))
    width = 0.8 / len(methods)
    for i, m in enumerate(methods):
        vals = [next((r.get("relmse_b1") or np.nan for r in rows
                      if r["scene"] == s and r["method"] == m), np.nan) for s in scenes]
        ax.bar(np.arange(len(scenes)) + (i - (len(methods) - 1) / 2) * width, vals, width,
               label=m)
    ax.set_yscale("log")
    ax.set_xticks(range(len(scenes)), scenes, rotation=20, fontsize=8)
    ax.set_ylabel("relMSE vs exact (block 1)")
    ax.set_title("tree_accuracy: missing bar = not supported / failed", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(True, axis="y", alpha=0.3)
    c.savefig(fig, path)


def plot_maps(path, maps: dict) -> None:
    """Per scene: the reference (tone-mapped) and log10 |error| of the
    MAPPED methods, block-averaged over MAP_BLOCK² pixels, shared colour scale."""
    import numpy as np

    from episcatter.metrics import block_average

    plt = c.pyplot()
    scenes = list(maps)
    cols = 1 + len(MAPPED)
    fig, axes = plt.subplots(len(scenes), cols, figsize=(2.3 * cols + 0.6, 1.8 * len(scenes)),
                             squeeze=False)
    im = None
    for row, scene in zip(axes, scenes):
        ref = block_average(maps[scene]["reference"], MAP_BLOCK)
        row[0].imshow(np.clip(ref / max(np.percentile(ref, 99.5), 1e-12), 0, 1) ** (1 / 2.2))
        row[0].set_ylabel(scene, fontsize=7)
        for ax, label in zip(row[1:], MAPPED):
            if label in maps[scene]:
                im = ax.imshow(maps[scene][label], vmin=-7, vmax=-1, cmap="magma")
        for ax, title in zip(row, ("reference", *MAPPED)):
            ax.set_xticks([])
            ax.set_yticks([])
            if scene == scenes[0]:
                ax.set_title(title, fontsize=7)
    if im is not None:
        fig.colorbar(im, ax=axes, shrink=0.6, label="log10 |error| (sum of RGB)")
    fig.savefig(path, dpi=72)
    plt.close(fig)


def main(argv=None) -> list[dict]:
    run = c.start_run(sys.modules[__name__], argv, SUITE, QUICK_SCENES)
    args, s, repeats, out = run.args, run.settings, run.repeats, run.out
    rows, maps = [], {}
    for name in run.scenes:
        rows += measure_scene(name, s, repeats, progress=not args.quick, maps=maps)
        print(f"{name}: done (load {c.load_average()})", flush=True)
    note = c.reference_note(s["reference_steps"])
    text = (f"# tree_accuracy ({s['width']}x{s['height']}, 1 spp)\n\n"
            f"Against the {note}; relMSE eps = 1e-2. Times: median of {repeats} warm runs "
            f"after a warm-up, interleaved, on {c.environment()['drjit_threads']} threads; "
            f"load average (1/5/15 min) {rows[0]['load_before']} before, "
            f"{rows[-1]['load_after']} after. 'black ref px': share of pixels the reference "
            "renders exactly 0 (fully shadowed); 'max there' / 'px > 1e-4 there': the "
            "method's light on them. HDR-FLIP takes its exposure range from the reference, "
            "so where most of it is black (beam) even 1e-7 residues there drive FLIP "
            "towards 1.\n\n" + table(rows))
    print(text)
    settings = {"name": NAME, **s, "repeats": repeats, "methods": METHODS,
                "scenes": run.scenes, "reference": note, "eps": 1e-2,
                "blocks": list(c.BLOCKS), "quick": args.quick}
    c.write_csv(out / "accuracy.csv", rows)
    c.write_json(out / "accuracy.json", settings, rows)
    c.write_text(out / "table.md", text)
    plot(out / "accuracy.png", rows)
    plot_maps(out / "error_maps.png", maps)
    return rows


if __name__ == "__main__":
    main()
