"""Error of ``fourier_filter``'s transmittance weighting against optical thickness.

Mirrors Klehm et al. 2014, **§3.2 / Fig. 3** ("average visibility gives
plausible results, but ... the difference increases with the thickness of
the participating media"; the reference-ray weights of Eq. 11 with the
bisectrix or the min-max optimal reference ray), with numbers instead of
insets.  The paper has no table for it; this is the measurement behind
that sentence.

One scene (``nave_offscreen``, 640x480, 1 spp at the pixel centres), its
σt varied so that the optical thickness ``τ = σt · scene size`` (scene size
= the diagonal of the medium box, ``SceneParams.scene_extent``) runs from
0.01 to 10 (the scene's own σt = 0.04 m⁻¹ is τ ≈ 2.1).  Everything else is
``fourier_filter``'s default (32 coefficients, automatic slices and light
rays), so the four weightings share the rectified shadow map:

``average``                 §3.1, uniform weights (average visibility)
``reference_ray bisectrix`` §3.2, Eq. 11 weights of the bisectrix ray
``reference_ray optimal``   §3.2, the min-max optimal reference ray
``exact``                   every view ray's own weights (separated kernel;
                            beyond the paper)

Errors: each weighting against ``exact`` (isolates the weighting error: the
same shadow map, series and slices) and every weighting against the exact
working reference (``raymarch visibility=exact``, 2048 steps;
:func:`experiments.common.exact_reference`).  Because the image's
brightness scales with σs = albedo · σt over four decades, the headline
metric is the **normalised relMSE**: both images divided by the mean of the
one compared against, then relMSE with eps 1e-2 (a pixel darker than 10 %
of the mean is regularised); the plain relMSE (absolute eps 1e-2) and the
mean ratio are in the CSV too.

Times: median of the warm runs per weighting (interleaved rounds, one
process), to check the paper's "weighting has practically no impact on
performance" (``exact`` runs one filter per kernel component).

Writes ``results/fourier_weights/``: ``weights.csv``, ``weights.json``,
``table.md``, ``weights.png``.
``python -m experiments.fourier_weights [--quick] [--repeats N] [--out DIR]``.
"""
from __future__ import annotations

import sys

import numpy as np

from episcatter import metrics

from . import common as c
from .fourier_table2 import load_text, timing_columns

NAME = "fourier_weights"
SCENE = "nave_offscreen"
#: label -> fourier_filter properties
MODES = {
    "average": {"weights": "average"},
    "bisectrix": {"weights": "reference_ray", "reference": "bisectrix"},
    "optimal": {"weights": "reference_ray", "reference": "optimal"},
    "exact": {"weights": "exact"},
}
BASELINE = "exact"


def settings_for(quick: bool) -> dict:
    """Resolution, optical thicknesses and reference steps."""
    if quick:
        return {"width": 64, "height": 48, "taus": [0.1, 3.0], "reference_steps": 128}
    return {"width": 640, "height": 480, "taus": [0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0],
            "reference_steps": c.REFERENCE_STEPS}


def scene_size(path: str, defines: dict) -> float:
    """The medium box diagonal [m] (what τ = σt · size is measured with)."""
    from integrators.core.scene_params import SceneParams

    return SceneParams.from_scene(c.load(path, defines)).scene_extent


def normalised_relmse(img, ref) -> float:
    """relMSE (eps 1e-2) of both images divided by the mean of ``ref``."""
    m = float(np.mean(ref))
    return metrics.relmse_absolute(np.asarray(img) / m, np.asarray(ref) / m) if m > 0 else float("nan")


def compare_pair(img, ref, prefix: str) -> dict:
    """``<prefix>_relmse_norm``, ``<prefix>_relmse``, ``<prefix>_mean_ratio``."""
    return {f"{prefix}_relmse_norm": normalised_relmse(img, ref),
            f"{prefix}_relmse": metrics.relmse_absolute(img, ref),
            f"{prefix}_mean_ratio": metrics.mean_ratio(img, ref)}


def measure_tau(scene_name: str, tau: float, size: float, s: dict, repeats: int,
                progress: bool) -> list[dict]:
    """Every weighting at one optical thickness: times and errors."""
    path = c.scene_file(scene_name)
    sigma_t = tau / size
    defines = {**c.resolution(s["width"], s["height"]), "sigma_t": f"{sigma_t:.9g}"}
    ref, info = c.exact_reference(path, defines, s["reference_steps"], progress=progress)
    scene = c.load(path, defines)
    integs = {label: c.build("fourier_filter", props) for label, props in MODES.items()}
    load_before = c.load_average()
    timed = c.time_renders(scene, integs, repeats=repeats, progress=progress)
    load_after = c.load_average()
    base = timed[BASELINE].get("image")
    rows = []
    for label, props in MODES.items():
        t = timed[label]
        row = {"scene": scene_name, "tau": tau, "sigma_t": sigma_t, "scene_size_m": size,
               "weights": label, "params": props, "width": s["width"], "height": s["height"],
               "status": t.get("error", "ok"), "load_before": load_before,
               "load_after": load_after, "reference": info["path"]}
        if "error" not in t:
            row.update(timing_columns(t))
            row.update(compare_pair(t["image"], ref, "vs_reference"))
            if base is not None:
                row.update(compare_pair(t["image"], base, "vs_exact_weights"))
            row["flip_vs_reference"] = c.errors(t["image"], ref, blocks=(1,))["flip_b1"]
        rows.append(row)
    return rows


# --------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------

def error_table(rows: list[dict]) -> str:
    """Normalised relMSE per τ: each weighting vs exact weights | vs reference."""
    taus = sorted({r["tau"] for r in rows})
    header = ["τ = σt·size", "σt [1/m]"]
    header += [f"{m} vs exact weights" for m in MODES if m != BASELINE]
    header += [f"{m} vs reference" for m in MODES]
    body = []
    for tau in taus:
        by = {r["weights"]: r for r in rows if r["tau"] == tau}
        cells = [c.fmt(tau), c.fmt(by[BASELINE]["sigma_t"])]
        cells += [c.fmt(by[m].get("vs_exact_weights_relmse_norm")) for m in MODES if m != BASELINE]
        cells += [c.fmt(by[m].get("vs_reference_relmse_norm")) for m in MODES]
        body.append(cells)
    return c.markdown_table(header, body)


def time_table(rows: list[dict]) -> str:
    """Median scattering time [ms] per weighting and τ, and the mean ratio."""
    taus = sorted({r["tau"] for r in rows})
    header = ["τ"] + [f"{m} scattering [ms]" for m in MODES] + \
        [f"{m} mean ratio vs ref" for m in MODES]
    body = []
    for tau in taus:
        by = {r["weights"]: r for r in rows if r["tau"] == tau}
        body.append([c.fmt(tau)] + [c.fmt(1000 * by[m].get("scattering_s", float("nan")))
                                    for m in MODES]
                    + [c.fmt(by[m].get("vs_reference_mean_ratio"), 4) for m in MODES])
    return c.markdown_table(header, body)


def plot(path, rows: list[dict]) -> None:
    """Normalised relMSE vs τ (log-log): vs exact weights (solid), vs the
    raymarch reference (dashed)."""
    plt = c.pyplot()
    fig, ax = plt.subplots(figsize=(6, 4.2))
    for label in MODES:
        mine = sorted((r for r in rows if r["weights"] == label and r["status"] == "ok"),
                      key=lambda r: r["tau"])
        taus = [r["tau"] for r in mine]
        if label != BASELINE:
            (line,) = ax.plot(taus, [r["vs_exact_weights_relmse_norm"] for r in mine], "o-",
                              label=f"{label} vs exact weights")
            color = line.get_color()
        else:
            color = "k"
        ax.plot(taus, [r["vs_reference_relmse_norm"] for r in mine], "--", marker=".",
                color=color, alpha=0.6, label=f"{label} vs reference")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("optical thickness τ = σt · medium-box diagonal")
    ax.set_ylabel("relMSE of mean-normalised images")
    ax.set_title("fourier_filter weights (nave_offscreen)", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    c.savefig(fig, path)


def report(rows, s, repeats, scene_name, size) -> str:
    loads = [r["load_before"] for r in rows] + [r["load_after"] for r in rows]
    return "\n\n".join([
        f"# fourier_weights: weighting error vs optical thickness ({scene_name}, "
        f"{s['width']}x{s['height']})",
        f"τ = σt · {size:.2f} m (medium-box diagonal).  Normalised relMSE = relMSE (eps 1e-2) "
        "after dividing both images by the mean of the one compared against.  Reference: "
        f"{c.reference_note(s['reference_steps'])} (block 1).  Times: median of {repeats} warm "
        f"runs, interleaved, one process; {load_text(loads)}.",
        "## Normalised relMSE", error_table(rows),
        "## Time and energy", time_table(rows)])


def main(argv=None):
    run = c.start_run(sys.modules[__name__], argv, [SCENE], [SCENE])
    args, s, repeats, out = run.args, run.settings, run.repeats, run.out
    scene_name = run.scenes[0]
    path = c.scene_file(scene_name)
    size = scene_size(path, c.resolution(s["width"], s["height"]))
    rows = []
    for tau in s["taus"]:
        rows += measure_tau(scene_name, tau, size, s, repeats, progress=not args.quick)
        print(f"tau={tau}: done (load {c.load_average()})", flush=True)
    text = report(rows, s, repeats, scene_name, size)
    print(text)
    settings = {"name": NAME, "scene": scene_name, **s, "scene_size_m": size,
                "modes": MODES, "baseline": BASELINE, "repeats": repeats,
                "reference": c.reference_note(s["reference_steps"]),
                "normalised_relmse": "relmse(img / mean(ref), ref / mean(ref), eps=1e-2)",
                "quick": args.quick}
    c.write_csv(out / "weights.csv", rows)
    c.write_json(out / "weights.json", settings, rows)
    c.write_text(out / "table.md", text)
    plot(out / "weights.png", rows)
    return rows


if __name__ == "__main__":
    main()
