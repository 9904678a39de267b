"""``episcatter render SCENE [-i TYPE] [-p name=value]... [-D name=value]... [-o out.exr]``

Renders the scene with integrator TYPE (default: the scene's own), writes an
EXR with every layer the integrator produces and an sRGB PNG preview, and
prints the time and, when a cached reference of the same scene, defines and
resolution exists (``episcatter reference``), the error against it.
"""
from __future__ import annotations

import os
import time

import drjit as dr
import numpy as np

from .imageio import write_exr, write_png_preview
from .scene_loading import load_scene, make_integrator, parse_assignments


def add_arguments(p):
    p.add_argument("scene", help="Mitsuba XML scene file")
    p.add_argument("-i", "--integrator", help="integrator type (raymarch, volpath, ...)")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE",
                   help="integrator property (repeatable)")
    p.add_argument("-D", "--define", action="append", default=[], metavar="NAME=VALUE",
                   help="XML default, e.g. -D res_x=640 (repeatable)")
    p.add_argument("-o", "--output", help="output EXR (default: <scene>_<type>.exr here)")
    p.add_argument("--spp", type=int, default=0, help="samples per pixel (0: integrator's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--exposure", default="auto", help="PNG preview exposure in stops, or 'auto'")
    p.add_argument("--reference", help="reference EXR to compare with (default: the cached "
                                       "volpath reference, if any)")
    p.add_argument("--block", type=int, default=1, help="block averaging for the comparison")


def _layers_as_numpy(integ, scene, seed, spp):
    """Render once: (every layer as (H, W, C) numpy arrays, stage timings)."""
    if hasattr(integ, "render_layers"):
        result = integ.render_layers(scene, 0, seed, spp)
        return {k: np.array(v) for k, v in result.items()}, result.timings
    import mitsuba as mi
    img = mi.render(scene, integrator=integ, seed=seed, spp=spp)
    return {"full": np.array(img)[..., :3]}, {}


def find_reference(args, defines):
    if args.reference:
        return args.reference
    try:
        from .reference import find_cached_reference
    except ImportError:
        return None
    return find_cached_reference(args.scene, defines)


def run(args) -> int:
    defines = parse_assignments(args.define)
    props = parse_assignments(args.param)
    scene = load_scene(args.scene, defines)
    integ = make_integrator(args.integrator, props, scene)
    kind = args.integrator or "scene"
    t0 = time.perf_counter()
    layers, timings = _layers_as_numpy(integ, scene, args.seed, args.spp)
    dr.sync_thread()
    elapsed = time.perf_counter() - t0
    out = args.output or f"{os.path.splitext(os.path.basename(args.scene))[0]}_{kind}.exr"
    main = layers.get(getattr(integ, "output", "full"), layers["full"])
    write_exr(out, {"full": main, **{k: v for k, v in layers.items() if k != "full"}},
              metadata={"scene": os.path.abspath(args.scene), "integrator": kind,
                        "params": repr(props), "defines": repr(defines),
                        "time_s": f"{elapsed:.4f}"})
    png = os.path.splitext(out)[0] + ".png"
    exposure = args.exposure if args.exposure == "auto" else float(args.exposure)
    write_png_preview(png, main, exposure=exposure)
    h, w = main.shape[:2]
    print(f"rendered {args.scene} ({w}x{h}) with {kind} in {elapsed:.3f} s "
          "(includes kernel compilation on a first run)")
    if timings:
        print("  stages: " + ", ".join(f"{k} {v:.3f} s" for k, v in timings.items()))
    print(f"  wrote {out} and {png}")
    ref = find_reference(args, defines)
    if ref:
        from .imageio import read_rgb
        from .metrics import compare
        m = compare(main, read_rgb(ref), block=args.block)
        print(f"  vs reference {ref}: relMSE {m['relmse']:.3e} (eps {m['eps']}), "
              f"RMSE {m['rmse']:.3e}, FLIP {m['flip']:.4f}, mean ratio {m['mean_ratio']:.4f}")
    else:
        print("  no cached reference for this scene/resolution: "
              "run `episcatter reference SCENE` to make one")
    return 0
