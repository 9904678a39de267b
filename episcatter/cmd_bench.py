"""``episcatter bench SCENE... -i TYPE... [-p name=value]... [--sweep name=v1,v2,...]...
[-D name=value]... [--reference volpath|exact|none] [--ref-spp N] [--repeats 3] [--block K] [--out DIR]
[--frames N [--warm-repeats 3]]``

Times integrators on scenes over the cartesian product of the sweeps and
measures their error against a cached reference (see
:mod:`episcatter.bench`).  Writes ``bench.csv``, ``bench.json`` and
``bench.png`` into ``--out`` (default ``results/bench/<scene stems>``) and
prints the table.  Parameter names may be scoped to one integrator as
``TYPE.name`` (``--sweep raymarch.steps=16,64``); ``spp`` is passed to
``mi.render``.  Exit status 1 if any job failed (its error is in the table).
The CLI (``episcatter/cli.py``) wires this module in through
:func:`add_arguments` and :func:`run`.

``--frames N`` times an animation instead (:mod:`episcatter.flythrough`):
each scene × integrator renders a fly-through of N frames (the camera,
the light, then the medium change in place between frames) at 1 spp, and
the per-frame table is printed: wall time of the frame's first render,
warm time (median of ``--warm-repeats`` more renders of it), JIT kernels
launched / compiled and the compile time.  No reference, no sweeps; with
``--out`` the rows are also written to ``DIR/frames.csv``.
"""
from __future__ import annotations

import argparse
import os

from . import metrics
from .bench import format_table, run_bench
from .distributed import add_cluster_arguments
from .reference import DEFAULT_EXACT_STEPS
from .scene_loading import parse_assignments, parse_value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``bench`` arguments to ``parser``."""
    parser.add_argument("scenes", nargs="+", metavar="SCENE", help="Mitsuba XML scene files")
    parser.add_argument("-i", "--integrator", dest="integrators", nargs="+", action="extend",
                        required=True, metavar="TYPE",
                        help="integrator types to benchmark (raymarch, volpath, ...)")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME=VALUE",
                        help="fixed parameter, TYPE.name for one integrator only (repeatable)")
    parser.add_argument("--sweep", action="append", default=[], metavar="NAME=V1,V2,...",
                        help="parameter values to sweep (repeatable; cartesian product)")
    parser.add_argument("-D", "--define", action="append", default=[], metavar="NAME=VALUE",
                        help="XML default, e.g. -D res_x=320 (repeatable)")
    parser.add_argument("--reference", choices=("volpath", "exact", "none"), default="exact",
                        help="reference for the errors: exact (raymarch visibility=exact, "
                             "default: at the pixel centres for 1-spp jobs, antialiased for "
                             "the others), volpath (ground truth) or none")
    parser.add_argument("--ref-spp", type=int, default=None,
                        help="reference samples per pixel (default: see --reference; giving "
                             "it fixes one reference for every job)")
    parser.add_argument("--ref-chunk", type=int, default=None, help="reference spp per chunk")
    parser.add_argument("--ref-steps", type=int, default=None,
                        help=f"steps of the exact reference (default {DEFAULT_EXACT_STEPS})")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per job (median)")
    parser.add_argument("--block", type=int, default=1, metavar="K",
                        help="compare KxK block averages (matched footprint; default 1)")
    parser.add_argument("--eps", type=float, default=metrics.DEFAULT_EPS,
                        help="relMSE regularizer (default: %(default)g)")
    parser.add_argument("--eps-mode", choices=metrics.EPS_MODES, default=metrics.DEFAULT_EPS_MODE,
                        help="relative (scale-free, default): eps*mean(ref)^2; absolute: eps "
                             "(the first sessions' numbers)")
    parser.add_argument("--out", default=None, metavar="DIR",
                        help="output folder (default: results/bench/<scene stems>)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    parser.add_argument("--frames", type=int, default=None, metavar="N",
                        help="time an N-frame fly-through (camera, light, medium change "
                             "between frames) and print the per-frame table: kernels "
                             "compiled per frame, first vs warm render time")
    parser.add_argument("--warm-repeats", type=int, default=3, metavar="K",
                        help="with --frames: warm renders of each frame (median; default 3)")
    add_cluster_arguments(parser, "jobs", note="; one timed job per machine: workers need "
                          "--resources machine=1")


def parse_sweeps(items) -> dict:
    """['steps=16,64'] -> {'steps': [16, 64]}."""
    sweeps = {}
    for item in items or ():
        if "=" not in item:
            raise ValueError(f"--sweep '{item}' is not of the form name=v1,v2,...")
        name, values = item.split("=", 1)
        parsed = [parse_value(v) for v in values.split(",") if v.strip()]
        if not parsed:
            raise ValueError(f"--sweep '{item}' has no values.")
        sweeps[name.strip()] = parsed
    return sweeps


def default_out_dir(scenes) -> str:
    stems = "+".join(os.path.splitext(os.path.basename(s))[0] for s in scenes)
    return os.path.join("results", "bench", stems)


def run_frames(args: argparse.Namespace) -> int:
    """``--frames N``: a fly-through per scene × integrator, per-frame tables."""
    import csv

    from .bench import params_for
    from .flythrough import FRAME_COLUMNS, fly_through, format_frames, summarize_frames
    from .scene_loading import load_scene, make_integrator

    if args.frames < 1 or args.warm_repeats < 1:
        raise ValueError("--frames and --warm-repeats must be >= 1.")
    if args.sweep:
        raise ValueError("--frames does not sweep: give fixed values with -p name=value.")
    defines = parse_assignments(args.define)
    params = parse_assignments(args.param)
    rows = []
    for scene_path in args.scenes:
        for kind in args.integrators:
            props = params_for(kind, params)
            spp = int(props.pop("spp", 1) or 1)
            scene = load_scene(scene_path, defines)
            integrator = make_integrator(kind, props)
            frames = fly_through(scene, integrator, frames=args.frames,
                                 warm_repeats=args.warm_repeats, spp=spp)
            title = f"{os.path.basename(scene_path)} {kind} {props or ''}".strip()
            print(format_frames(frames, title))
            s = summarize_frames(frames)
            print(f"\nfirst render {s['first_s']:.3g} s; new frames {s['new_mean_s']:.3g} s mean, "
                  f"{s['new_max_s']:.3g} s max; warm {s['warm_s']:.3g} s; "
                  f"{s['compiled_mean']:.3g} kernels compiled per new frame\n")
            rows += [{"scene": scene_path, "integrator": kind, "params": repr(props),
                      "spp": spp, **{k: r[k] for k in FRAME_COLUMNS}} for r in frames]
    print("wall = first render of the frame (compile + run); warm = median of "
          f"{args.warm_repeats} more renders; ratio = wall / warm; compile share = compile "
          "time / wall; compiled = kernels found neither in memory nor on disk")
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        path = os.path.join(args.out, "frames.csv")
        with open(path, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        print(f"wrote {path}")
    return 0


def run(args: argparse.Namespace) -> int:
    """Run the benchmark described by parsed ``args``; returns the exit status."""
    if getattr(args, "frames", None) is not None:
        return run_frames(args)
    metrics.check_eps(args.eps, args.eps_mode)
    if args.repeats < 1:
        raise ValueError(f"--repeats {args.repeats} must be >= 1.")
    out = args.out or default_out_dir(args.scenes)
    results = run_bench(args.scenes, args.integrators, sweeps=parse_sweeps(args.sweep),
                        defines=parse_assignments(args.define), reference=args.reference,
                        out_dir=out, repeats=args.repeats, params=parse_assignments(args.param),
                        block=args.block, eps=args.eps, ref_spp=args.ref_spp,
                        ref_chunk=args.ref_chunk, ref_steps=args.ref_steps,
                        progress=not args.no_progress, eps_mode=args.eps_mode,
                        scheduler=args.scheduler, workers=args.workers)
    print(format_table(results))
    print(f"times: median of {args.repeats} runs after a warm-up (first = compile + first run); "
          f"errors: {metrics.eps_text(args.eps, args.eps_mode)} vs the {args.reference} "
          f"reference, {args.block}x{args.block} block averages; convention = the render's "
          "pixel footprint / the reference's (centres = 1 spp at the pixel centres, aa = "
          "antialiased, '!' = mismatch)")
    print(f"wrote {os.path.join(out, 'bench.csv')}, bench.json, bench.png")
    return 1 if any(r.get("error") for r in results) else 0
