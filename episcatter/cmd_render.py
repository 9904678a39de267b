"""``episcatter render SCENE [-i TYPE] [-p name=value]... [-D name=value]... [-o out.exr]``

Renders the scene with integrator TYPE (default: the scene's own), writes an
EXR with every layer the integrator produces and an sRGB PNG preview next
to it (``-o x.png`` writes ``x.exr`` + ``x.png``), and prints

- the first run's time (kernel compilation + first run) and, after it, the
  median of ``--repeats`` warm runs (DESIGN §5), with the stages of the
  median warm run summing to its total (``other``: what no stage covers);
- the error against a reference in the same pixel convention
  (:mod:`episcatter.conventions`): a 1-spp render at the pixel centres
  against the exact marcher at the pixel centres (rendered once, cached),
  an antialiased render against the cached volpath reference if there is
  one; ``--reference FILE`` compares with a file, ``--check none`` skips it.

Everything a render needs is checked before it starts (output folder and
suffix, ``--spp``, ``--eps``).
"""
from __future__ import annotations

import os
import statistics
import time

import drjit as dr
import numpy as np

from . import metrics
from .bench import stage_breakdown
from .conventions import (ANTIALIASED, PIXEL_CENTRES, comparison_text, pixel_centre_reference,
                          reference_convention, render_convention)
from .imageio import output_paths, write_exr, write_png_preview
from .scene_loading import check_volpath_medium, load_scene, make_integrator, parse_assignments


def add_arguments(p):
    p.add_argument("scene", help="Mitsuba XML scene file")
    p.add_argument("-i", "--integrator", help="integrator type (raymarch, volpath, ...)")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE",
                   help="integrator property (repeatable)")
    p.add_argument("-D", "--define", action="append", default=[], metavar="NAME=VALUE",
                   help="XML default, e.g. -D res_x=640 (repeatable)")
    p.add_argument("-o", "--output", help="output .exr (a .png preview is written beside it; "
                                          "default: <scene>_<type>.exr here)")
    p.add_argument("--spp", type=int, default=0,
                   help="samples per pixel (0: the integrator's, else the scene's sampler)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--repeats", type=int, default=1,
                   help="warm runs timed after the first run (median; 0: first run only)")
    p.add_argument("--exposure", default="auto", help="PNG preview exposure in stops, or 'auto'")
    p.add_argument("--check", choices=("auto", "none"), default="auto",
                   help="auto: compare with a reference in the render's pixel convention "
                        "(default); none: no comparison")
    p.add_argument("--reference", help="reference EXR to compare with (instead of --check auto)")
    p.add_argument("--ref-steps", type=int, default=None,
                   help="steps of the pixel-centre exact reference (default: see "
                        "`episcatter reference`)")
    p.add_argument("--block", type=int, default=1, help="block averaging for the comparison")
    p.add_argument("--eps", type=float, default=metrics.DEFAULT_EPS, help="relMSE regulariser")
    p.add_argument("--eps-mode", choices=metrics.EPS_MODES, default=metrics.DEFAULT_EPS_MODE,
                   help="relative (scale-free, default): eps*mean(ref)^2; absolute: eps")


def check_arguments(args) -> None:
    """Refuse bad numbers before anything is loaded or rendered."""
    if args.spp < 0:
        raise ValueError(f"--spp {args.spp}: samples per pixel must be >= 1 "
                         "(or 0 for the integrator's / scene's own count).")
    if args.repeats < 0:
        raise ValueError(f"--repeats {args.repeats} must be >= 0.")
    if args.block < 1:
        raise ValueError(f"--block {args.block} must be >= 1.")
    metrics.check_eps(args.eps, args.eps_mode)
    if args.reference and not os.path.isfile(args.reference):
        raise FileNotFoundError(f"reference '{args.reference}' does not exist.")


def render_layers(integ, scene, seed, spp) -> tuple[dict, dict, dict]:
    """Render once: (every layer as (H, W, C) NumPy arrays, kernels finished;
    the render's stage timings and its stats, {} for plain Mitsuba
    integrators)."""
    if hasattr(integ, "render_layers"):
        result = integ.render_layers(scene, 0, seed, spp)
        dr.eval(*result.values())
        dr.sync_thread()
        return ({k: np.array(v) for k, v in result.items()}, dict(result.timings),
                dict(result.stats))
    from .reference import render_rgb
    return {"full": render_rgb(scene, integ, spp=spp, seed=seed)}, {}, {}


def timed_runs(integ, scene, seed, spp, repeats) -> dict:
    """First run (compile + run) and ``repeats`` warm runs: their seconds,
    the layers of the last run and the stage breakdown of the median warm
    run (:func:`episcatter.bench.stage_breakdown`)."""
    runs = []
    for _ in range(1 + int(repeats)):
        t0 = time.perf_counter()
        layers, timings, stats = render_layers(integ, scene, seed, spp)
        seconds = time.perf_counter() - t0
        runs.append((seconds, timings))
    warm = runs[1:]
    out = {"first_s": runs[0][0], "warm_s": [s for s, _ in warm], "layers": layers,
           "stages": None, "stats": stats}
    if warm:
        out["median_s"] = statistics.median(out["warm_s"])
        seconds, stages = min(warm, key=lambda r: abs(r[0] - out["median_s"]))
        out["stages"] = stage_breakdown(stages, seconds) if stages else None
    return out


def print_auto_choice(stats: dict) -> None:
    """What ``quality="auto"`` chose: the settings, the relMSE it expects
    (measured by its probe or predicted by its model) against the budget,
    and the probe's cost."""
    if "auto_settings" not in stats:
        return
    chosen = ", ".join(f"{k}={v}" for k, v in stats["auto_settings"].items()) or "the defaults"
    print(f"  quality=auto chose {chosen} for error_budget {stats['error_budget']:g}")
    expected = stats.get("auto_predicted_relmse")
    if expected is None:
        print("    expected relMSE: unknown (the probe saw no error to model)")
    else:
        how = ("measured by the probe" if stats.get("auto_predicted_from") == "measured"
               else "predicted by the rule's error model")
        print(f"    expected relMSE {expected:.2e} ({how}, pixel centres)")
    if stats.get("auto_over_budget"):
        print("    warning: no setting the rule considers is expected to reach the budget")
    print(f"    probe: {stats.get('auto_probe_s', 0.0):.3f} s on "
          f"{stats.get('auto_probe_pixels', 0)} pixels"
          + (", its render reused" if stats.get("auto_reused") else ""))


def print_times(t: dict) -> None:
    print(f"  first run {t['first_s']:.3f} s (kernel compilation + first run)")
    if not t["warm_s"]:
        print("  no warm runs (--repeats 0): the time above includes compilation")
        return
    print(f"  warm {t['median_s']:.3f} s (median of {len(t['warm_s'])} run(s); "
          f"min {min(t['warm_s']):.3f}, max {max(t['warm_s']):.3f})")
    if t["stages"]:
        top, parts = t["stages"]
        print("  stages of the median warm run: " +
              " + ".join(f"{k} {v:.3f}" for k, v in top.items() if k != "total") +
              f" = {top['total']:.3f} s")
        if parts:
            print("    inside scattering: " + ", ".join(f"{k} {v:.3f} s" for k, v in parts.items()))


def reference_for(args, defines, convention) -> tuple[str | None, str | None, str]:
    """(reference EXR or None, its convention, what was done to get it)."""
    if args.reference:
        from .reference import load_reference
        _, info = load_reference(args.reference)
        return args.reference, reference_convention(info) if info else None, "given"
    if args.check == "none":
        return None, None, "--check none"
    if convention == PIXEL_CENTRES:
        _, info = pixel_centre_reference(args.scene, defines, args.ref_steps, progress=True)
        how = "cached" if info.get("cached") else "rendered now and cached"
        return info["path"], PIXEL_CENTRES, f"exact marcher at the pixel centres, {how}"
    from .reference import find_cached_reference
    path = find_cached_reference(args.scene, defines)
    return path, (ANTIALIASED if path else None), "cached volpath reference"


def print_comparison(main, args, defines, convention) -> None:
    from .imageio import read_rgb

    path, ref_convention, how = reference_for(args, defines, convention)
    if path is None:
        if how != "--check none":
            print(f"  no cached volpath reference for this {ANTIALIASED} render: run "
                  "`episcatter reference SCENE` (same -D) to make one")
        return
    ref = read_rgb(path)
    m = metrics.compare(main, ref, block=args.block, eps=args.eps, eps_mode=args.eps_mode)
    print(f"  vs reference {path} ({how})")
    print(f"    convention: {comparison_text(convention, ref_convention or 'unknown')}"
          + (f", {args.block}x{args.block} blocks" if args.block > 1 else ""))
    print(f"    relMSE {m['relmse']:.3e} ({m['relmse_convention']}), mean ratio "
          f"{m['mean_ratio']:.4f}, max error / peak {m['max_error_over_peak']:.3g}, "
          f"RMSE {m['rmse']:.3e}, FLIP {m['flip']:.4f}")
    if m["nonfinite_ref"]:
        print(f"    warning: the reference has {m['nonfinite_ref']} non-finite pixels "
              "(left out); a volpath reference of a medium with a zero sigma_t channel is NaN")


def run(args) -> int:
    check_arguments(args)
    kind = args.integrator or "scene"
    exr, png = output_paths(args.output or
                            f"{os.path.splitext(os.path.basename(args.scene))[0]}_{kind}.exr")
    defines = parse_assignments(args.define)
    props = parse_assignments(args.param)
    scene = load_scene(args.scene, defines)
    integ = make_integrator(args.integrator, props, scene)
    if integ.class_name() == "VolumetricPathIntegrator":
        check_volpath_medium(scene)
    convention, spp = render_convention(integ, scene, args.spp)
    t = timed_runs(integ, scene, args.seed, args.spp, args.repeats)
    layers = t["layers"]
    main = layers.get(getattr(integ, "output", "full"), layers["full"])
    elapsed = t.get("median_s", t["first_s"])
    write_exr(exr, {"full": main, **{k: v for k, v in layers.items() if k != "full"}},
              metadata={"scene": os.path.abspath(args.scene), "integrator": kind,
                        "params": repr(props), "defines": repr(defines), "spp": str(spp),
                        "pixel_convention": convention, "time_s": f"{elapsed:.4f}",
                        "first_run_s": f"{t['first_s']:.4f}"})
    exposure = args.exposure if args.exposure == "auto" else float(args.exposure)
    write_png_preview(png, main, exposure=exposure)
    h, w = main.shape[:2]
    print(f"rendered {args.scene} ({w}x{h}, {spp} spp, {convention}) with {kind}")
    print_times(t)
    print_auto_choice(t.get("stats", {}))
    print(f"  wrote {exr} and {png}")
    print_comparison(main, args, defines, convention)
    return 0
