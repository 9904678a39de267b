"""``episcatter reference SCENE [--spp N] [--chunk N] [-D name=value]... [-o out.exr] [--force]
[--scheduler ADDRESS | --workers K]``

Renders (or takes from the cache) the ground truth of a scene: Mitsuba's
``volpath`` with ``max_depth=2`` (``--kind exact``: ``raymarch
visibility=exact`` with ``--steps``), see :mod:`episcatter.reference`.
Writes the EXR (layers ``full``, ``half_a``, ``half_b``), its JSON sidecar
and an sRGB PNG preview; with ``-o`` the EXR and sidecar are copied there and
the preview goes next to the copy.  Prints the path, time and noise level.
``--scheduler``/``--workers`` render the chunks as Dask tasks (optional
extra ``[distributed]``, :mod:`episcatter.distributed`); the image is the
same bit for bit.  Finished chunks are stored as they complete: after
Ctrl-C, a killed worker or a lost scheduler, the same command again renders
only the missing chunks.
The CLI (``episcatter/cli.py``) wires this module in through
:func:`add_arguments` and :func:`run`.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys

from .distributed import add_cluster_arguments, require_dask, uses_dask
from .imageio import write_png_preview
from .reference import DEFAULT_CHUNK, DEFAULT_EXACT_STEPS, DEFAULT_SPP, KINDS, render_reference, sidecar_path
from .scene_loading import parse_assignments


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``reference`` arguments to ``parser``."""
    parser.add_argument("scene", help="Mitsuba XML scene file")
    parser.add_argument("--spp", type=int, default=None,
                        help="total samples per pixel, even (default: volpath "
                             f"{DEFAULT_SPP['volpath']}, exact {DEFAULT_SPP['exact']})")
    parser.add_argument("--chunk", type=int, default=None,
                        help="samples per pixel per render call (default: volpath "
                             f"{DEFAULT_CHUNK['volpath']}, exact {DEFAULT_CHUNK['exact']})")
    parser.add_argument("-D", "--define", action="append", default=[], metavar="NAME=VALUE",
                        help="XML default, e.g. -D res_x=640 (repeatable)")
    parser.add_argument("-o", "--output", help="also copy the EXR (+ .json sidecar) here")
    parser.add_argument("--force", action="store_true", help="re-render even if cached")
    parser.add_argument("--kind", choices=KINDS, default="volpath",
                        help="volpath (ground truth, default) or exact (raymarch "
                             "visibility=exact, the working reference)")
    parser.add_argument("--steps", type=int, default=None,
                        help=f"raymarch steps of --kind exact (default {DEFAULT_EXACT_STEPS})")
    parser.add_argument("--exposure", default="auto",
                        help="PNG preview exposure in stops, or 'auto' (default)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_cluster_arguments(parser, "chunks")


def _copy_out(path: str, output: str) -> str:
    """Copy the cached EXR and its sidecar to ``output``; returns ``output``."""
    folder = os.path.dirname(os.path.abspath(output))
    os.makedirs(folder, exist_ok=True)
    shutil.copyfile(path, output)
    shutil.copyfile(sidecar_path(path), sidecar_path(output))
    return output


def _noise_text(noise: dict) -> str:
    parts = [f"{k.replace('block_', 'block ')}: {v:.3e}" for k, v in noise.items()
             if k.startswith("block_")]
    return f"relMSE noise (eps {noise.get('eps', float('nan')):g}) " + ", ".join(parts)


def run(args: argparse.Namespace) -> int:
    """Make the reference described by parsed ``args``; returns the exit status."""
    defines = parse_assignments(args.define)
    if uses_dask(args.scheduler, args.workers):
        require_dask()          # the extra's name before any rendering
    try:
        rgb, info = render_reference(args.scene, defines, spp=args.spp, chunk=args.chunk,
                                     progress=not args.no_progress, force=args.force,
                                     kind=args.kind, steps=args.steps,
                                     scheduler=args.scheduler, workers=args.workers)
    except KeyboardInterrupt:
        print(f"episcatter reference: interrupted; the finished chunks are stored, run the "
              "same command again to render only the missing ones", file=sys.stderr)
        return 130
    path = _copy_out(info["path"], args.output) if args.output else info["path"]
    png = os.path.splitext(path)[0] + ".png"
    exposure = args.exposure if args.exposure == "auto" else float(args.exposure)
    write_png_preview(png, rgb, exposure=exposure)
    w, h = info["resolution"]
    how = "from the cache" if info.get("cached") else "rendered"
    print(f"{info['kind']} reference of {args.scene} ({w}x{h}, {info['spp']} spp) {how}")
    print(f"  integrator: {info['integrator']}")
    print(f"  render time: {info['wall_time_s']:.2f} s ({len(info['seeds'])} chunks of "
          f"<= {info['chunk']} spp; first chunk includes kernel compilation)")
    if info.get("chunks_resumed"):
        print(f"  resumed: {info['chunks_resumed']} chunks from an earlier run, "
              f"{info['chunks_rendered']} rendered now")
    print(f"  {_noise_text(info['relmse_noise'])}")
    print(f"  wrote {path} (+ {os.path.basename(sidecar_path(path))}, {os.path.basename(png)})")
    return 0
