"""``episcatter frontier SCENE... [-i TYPE...] [--budget quick|full] [-o DIR]
[--convention pixel_centre|antialiased]... [--size WxH] [--aa-size WxH] [-D name=value]...``

Sweeps each method's quality knobs on each scene, times every setting
(DESIGN §5), measures its scale-free relMSE in both error conventions
(DESIGN §2), keeps each method's Pareto frontier and reads speedups over the
``raymarch`` frontier at relMSE 1e-3, 1e-4 and 1e-5 (see
:mod:`episcatter.frontier`).  Writes runs.csv/json, speedups.csv, floor.csv,
table.md and one plot per scene into ``-o`` (default
``results/frontier/<budget>``) and prints table.md.  Set
``OPENBLAS_NUM_THREADS=1`` before timing.
"""
from __future__ import annotations

import argparse
import os

from . import frontier as fr
from .scene_loading import parse_assignments


def parse_size(text: str) -> tuple[int, int]:
    """'640x480' -> (640, 480)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"size {text!r} is not WIDTHxHEIGHT, e.g. 640x480") from None
    if w < 1 or h < 1:
        raise ValueError(f"size {text!r} must be positive")
    return w, h


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``frontier`` arguments to ``parser``."""
    parser.add_argument("scenes", nargs="+", metavar="SCENE", help="Mitsuba XML scene files")
    parser.add_argument("-i", "--integrator", dest="methods", nargs="+", action="extend",
                        metavar="TYPE", default=None,
                        help=f"methods to sweep (default: all of {sorted(fr.GRIDS)})")
    parser.add_argument("--budget", choices=fr.BUDGETS, default="quick",
                        help="settings grids and image sizes (default quick)")
    parser.add_argument("--convention", dest="conventions", action="append",
                        choices=fr.CONVENTIONS, default=None,
                        help="error convention(s) (default: both)")
    parser.add_argument("--size", default=None, metavar="WxH",
                        help="pixel-centre image size (default: the budget's)")
    parser.add_argument("--aa-size", default=None, metavar="WxH",
                        help="antialiased image size (default: the budget's)")
    parser.add_argument("-D", "--define", action="append", default=[], metavar="NAME=VALUE",
                        help="XML default (repeatable)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per setting (median)")
    parser.add_argument("--ref-spp", type=int, default=None,
                        help=f"jittered rays per pixel of the antialiased reference "
                             f"(default {fr.ANTIALIASED_REFERENCE_SPP})")
    parser.add_argument("--scheduler", default=None,
                        help="Dask scheduler address: run the tasks with "
                             "episcatter.distributed.map_runs")
    parser.add_argument("-o", "--out", default=None, metavar="DIR",
                        help="output folder (default results/frontier/<budget>)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def map_function(scheduler):
    """None (run locally) or a map over Dask workers."""
    if scheduler is None:
        return None
    try:
        from .distributed import map_runs
    except ImportError as exc:
        raise ImportError("--scheduler needs episcatter.distributed (and dask.distributed); "
                          "run without --scheduler to sweep locally") from exc
    return lambda fn, items: map_runs(fn, items, scheduler=scheduler)


def run(args: argparse.Namespace) -> int:
    """Run the sweep described by parsed ``args``; returns the exit status."""
    from .frontier_report import run_frontier

    if int(args.repeats) < 1:
        raise ValueError(f"--repeats {args.repeats} must be >= 1")
    sizes = {}
    if args.size:
        sizes["pixel_centre"] = parse_size(args.size)
    if args.aa_size:
        sizes["antialiased"] = parse_size(args.aa_size)
    out = args.out or os.path.join("results", "frontier", args.budget)
    rows = run_frontier(args.scenes, args.methods or sorted(fr.GRIDS), args.budget,
                        tuple(args.conventions or fr.CONVENTIONS), out,
                        fr.defines_for(args.budget, parse_assignments(args.define), sizes),
                        args.repeats, not args.no_progress, map_function(args.scheduler),
                        reference_spp=args.ref_spp)
    with open(os.path.join(out, "table.md")) as f:
        print(f.read())
    return 1 if any(r.get("error_message") for r in rows) else 0
