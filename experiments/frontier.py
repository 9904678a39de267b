"""Time-vs-error frontiers of every method on the whole suite (issue 16;
DESIGN §5): ``python -m experiments.frontier [--budget quick|full]
[--scenes ...] [--methods ...] [--quick]``.

Runs :func:`episcatter.frontier_report.run_frontier` over the suite scenes:
every method's settings grid (:mod:`episcatter.frontier`), both error
conventions (pixel centres against ``raymarch visibility=exact``; antialiased
against the exact marcher with many jittered rays per pixel, where
``volpath`` joins), each method's Pareto frontier, speedups over the
``raymarch`` frontier at relMSE 1e-3 / 1e-4 / 1e-5 and the captures' floor.
Writes ``results/frontier/<budget>/``.  ``--quick`` is the seconds-long
smoke run the tests use (tiny images and grids, written to
``results/frontier/tiny/`` unless ``--out``).

Also checks the antialiased reference against a volpath image of the same
scene and size (``aa_check.csv``): relMSE of the exact marcher's image
against volpath's, next to volpath's own noise.
"""
from __future__ import annotations

import argparse
import os


NAME = "frontier"
#: the seconds-long smoke run: a few settings per method at 32x24
TINY_GRIDS = {"raymarch": [{"steps": 32, "visibility": "exact"}, {"steps": 128, "visibility": "exact"},
                           {"steps": 64, "shadowmap_resolution": 256},
                           {"steps": 64, "visibility": "exact", "jitter": True, "spp": 4}],
              "epipolar_tree": [{"slice_spacing": 2.0}, {"slice_spacing": 1.0},
                                {"slice_spacing": 1.0, "spp": 4}],
              "fourier_filter": [{"coefficients": 16}, {"coefficients": 64}],
              "minmax_epipolar": [{}, {"initial_step": 4}],
              "volpath": [{"spp": 16}, {"spp": 64}]}
TINY_SIZES = {"pixel_centre": (32, 24), "antialiased": (32, 24)}


def parse(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--budget", choices=("quick", "full"), default="quick")
    p.add_argument("--scenes", nargs="+", default=None, help="suite stems (default: all)")
    p.add_argument("--methods", nargs="+", default=None, help="default: every registered one")
    p.add_argument("--conventions", nargs="+", default=None,
                   choices=("pixel_centre", "antialiased"))
    p.add_argument("--repeats", type=int, default=None, help="default 3 (1 with --quick)")
    p.add_argument("--ref-spp", type=int, default=None,
                   help="jittered rays per pixel of the antialiased reference")
    p.add_argument("--volpath-spp", type=int, default=4096,
                   help="volpath samples per pixel of the antialiased-reference check (0: skip)")
    p.add_argument("--size", default=None, metavar="WxH", help="pixel-centre size (default: the budget's)")
    p.add_argument("--aa-size", default=None, metavar="WxH", help="antialiased size (default: the budget's)")
    p.add_argument("--merge", nargs="+", default=None, metavar="DIR",
                   help="instead of sweeping, merge the runs.json of these output folders "
                        "(e.g. one per convention, run side by side) into --out")
    p.add_argument("--quick", action="store_true", help="tiny smoke run (tests)")
    p.add_argument("--out", default=None)
    return p.parse_args(argv)


def aa_check(scenes, defines_of, ref_spp, volpath_spp, progress) -> list[dict]:
    """The antialiased reference (exact marcher, jittered rays) against
    volpath at the same size: scale-free relMSE and mean ratio, and
    volpath's own noise from its two halves (same convention)."""
    from episcatter import frontier as fr
    from episcatter.reference import load_halves, load_reference, render_reference

    rows = []
    for scene in scenes:
        defines = defines_of(scene, "antialiased")
        exact, _ = load_reference(fr.make_reference(scene, defines, "antialiased",
                                                    progress=progress, spp=ref_spp))
        vol, info = render_reference(scene, defines, spp=volpath_spp, progress=progress)
        rows.append({"scene": os.path.basename(scene), "size": f"{defines['res_x']}x{defines['res_y']}",
                     "volpath_spp": info.get("spp"),
                     **{f"exact_vs_volpath_{k}": v for k, v in fr.image_errors(exact, vol).items()},
                     "volpath_noise": fr.scale_free_noise(*load_halves(info["path"]))})
    return rows


def merge(folders, out) -> int:
    """Write the reports of the runs of several sweeps (their runs.json)
    into ``out``, as if they were one sweep; aa_check.csv files are kept."""
    import json
    import shutil

    from episcatter.frontier_report import write_all

    if not out:
        raise ValueError("--merge needs --out DIR for the merged reports")
    rows, parts = [], []
    for folder in folders:
        with open(os.path.join(folder, "runs.json")) as f:
            doc = json.load(f)
        rows += doc["rows"]
        parts.append({"folder": folder, "settings": doc["settings"],
                      "environment": doc["environment"]})
        check = os.path.join(folder, "aa_check.csv")
        if os.path.isfile(check) and os.path.abspath(folder) != os.path.abspath(out):
            os.makedirs(out, exist_ok=True)
            shutil.copy(check, os.path.join(out, "aa_check.csv"))
    write_all(out, rows, {"merged_from": parts})
    with open(os.path.join(out, "table.md")) as f:
        print(f.read())
    return 0


def main(argv=None) -> int:
    import scenes as suite

    from episcatter import frontier as fr
    from episcatter.cmd_frontier import parse_size
    from episcatter.frontier_report import run_frontier, write_rows_csv

    args = parse(argv)
    if args.merge:
        return merge(args.merge, args.out)
    names = args.scenes or list(suite.SUITE)
    paths = [suite.path(n) for n in names]
    repeats = args.repeats or (1 if args.quick else 3)
    out = args.out or os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                   "results", NAME, "tiny" if args.quick else args.budget)
    sizes = dict(TINY_SIZES) if args.quick else {}
    if args.size:
        sizes["pixel_centre"] = parse_size(args.size)
    if args.aa_size:
        sizes["antialiased"] = parse_size(args.aa_size)
    defines_of = fr.defines_for(args.budget, sizes=sizes)
    methods = args.methods or sorted(fr.GRIDS)
    conventions = tuple(args.conventions or fr.CONVENTIONS)
    run_frontier(paths, methods, args.budget, conventions, out, defines_of, repeats,
                 progress=not args.quick, grids=TINY_GRIDS if args.quick else None,
                 reference_spp=(8 if args.quick else args.ref_spp))
    if "antialiased" in conventions and args.volpath_spp:
        rows = aa_check(paths, defines_of, 8 if args.quick else args.ref_spp,
                        64 if args.quick else args.volpath_spp, progress=not args.quick)
        write_rows_csv(os.path.join(out, "aa_check.csv"), rows)
    with open(os.path.join(out, "table.md")) as f:
        print(f.read())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
