"""The ``episcatter`` command line (DESIGN §4).

Each subcommand lives in its own ``cmd_<name>`` module exposing
``add_arguments(parser)`` and ``run(args) -> int``.  OpenBLAS is pinned to
one thread before any subcommand imports NumPy (DESIGN §5;
``OPENBLAS_NUM_THREADS`` set by the user wins).
"""
from __future__ import annotations

from .blas import pin_one_thread

pin_one_thread()   # before NumPy loads its BLAS (the subcommands import it)

import argparse  # noqa: E402
import importlib  # noqa: E402
import sys  # noqa: E402

COMMANDS = {
    "render": "render a scene with one of our integrators (or the scene's own)",
    "reference": "ground truth of a scene (volpath max_depth=2, or the exact ray marcher), cached",
    "compare": "error metrics of a test image against a reference",
    "bench": "time and error of integrators on scenes, with parameter sweeps",
    "epipolar": "epipolar geometry diagnostics of a scene",
    "frontier": "time-vs-error frontiers of every method and speedups read off them",
    "animate": "render an animation of moving shapes, reusing what they do not change",
}


def build_parser():
    parser = argparse.ArgumentParser(
        prog="episcatter",
        description="Single scattering with volumetric shadows for Mitsuba 3.")
    sub = parser.add_subparsers(dest="command", required=True)
    for name, help_text in COMMANDS.items():
        try:
            module = importlib.import_module(f"episcatter.cmd_{name}")
        except ModuleNotFoundError as err:
            if err.name != f"episcatter.cmd_{name}":
                raise
            continue
        p = sub.add_parser(name, help=help_text, description=help_text)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def user_error(err: BaseException) -> BaseException:
    """The error a user should see (see :func:`episcatter.scene_loading.unwrap_render_error`)."""
    from .scene_loading import unwrap_render_error
    return unwrap_render_error(err)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except (ValueError, FileNotFoundError, RuntimeError, ImportError) as err:
        err = user_error(err)
        print(f"episcatter {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
