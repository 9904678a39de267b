"""Are the renders of this checkout bit-identical to those of another?

A refactoring that claims "behaviour unchanged" shows it with this script:
save every suite scene rendered by every integrator at its defaults, once
from the checkout before the change and once after, and compare them with
``np.array_equal`` (NaN equal to NaN).

``python -m experiments.renders_identical save DIR [--sizes 160x120,48x36]
[--methods ...] [--scenes ...]`` writes ``DIR/<size>/<method>/<scene>.npy``
(the ``full`` output, one sample per pixel);
``python -m experiments.renders_identical compare DIR_A DIR_B`` prints one
line per image that differs (or is missing) and exits with 1 if any does.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

SCENES = ["beam", "grove", "hall", "nave_offscreen", "nave_onscreen", "point_fog", "spot_room",
          "sun_ahead", "sun_behind", "sun_room", "terrain"]
METHODS = ["raymarch", "epipolar_tree", "fourier_filter", "minmax_epipolar"]
SIZES = "160x120,48x36"


def save(folder: Path, sizes: list[tuple[int, int]], methods: list[str],
         scenes: list[str]) -> int:
    """Render and save; returns the number of images written."""
    from . import common as c
    import mitsuba as mi
    from tqdm.auto import tqdm

    jobs = [(w, h, m, s) for (w, h) in sizes for m in methods for s in scenes]
    with tqdm(total=len(jobs), desc="renders", unit="image") as bar:
        for w, h, method, scene_name in jobs:
            scene = c.load(c.scene_file(scene_name), {"res_x": w, "res_y": h, "spp": 1})
            image = np.array(mi.render(scene, integrator=mi.load_dict({"type": method})))
            out = folder / f"{w}x{h}" / method
            out.mkdir(parents=True, exist_ok=True)
            np.save(out / f"{scene_name}.npy", image)
            bar.update(1)
    return len(jobs)


def compare(a: Path, b: Path) -> list[str]:
    """One line per image of ``a`` that is missing from ``b`` or differs."""
    problems = []
    files = sorted(p.relative_to(a) for p in a.rglob("*.npy"))
    if not files:
        return [f"{a}: no .npy images"]
    for rel in files:
        other = b / rel
        if not other.exists():
            problems.append(f"{rel}: missing in {b}")
            continue
        x, y = np.load(a / rel), np.load(other)
        if x.shape != y.shape or not np.array_equal(x, y, equal_nan=True):
            diff = (np.nanmax(np.abs(x - y)) if x.shape == y.shape else "shape")
            problems.append(f"{rel}: differs (max |a - b| = {diff})")
    print(f"{len(files) - len(problems)} of {len(files)} images identical")
    return problems


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    s = sub.add_parser("save", help="render every suite scene with every method and save")
    s.add_argument("folder", type=Path)
    s.add_argument("--sizes", default=SIZES, help=f"comma-separated WxH (default {SIZES})")
    s.add_argument("--methods", nargs="+", default=METHODS)
    s.add_argument("--scenes", nargs="+", default=SCENES)
    k = sub.add_parser("compare", help="compare two saved folders image by image")
    k.add_argument("a", type=Path)
    k.add_argument("b", type=Path)
    args = parser.parse_args(argv)
    if args.command == "save":
        sizes = [tuple(int(v) for v in size.split("x")) for size in args.sizes.split(",")]
        save(args.folder, sizes, args.methods, args.scenes)
        return 0
    problems = compare(args.a, args.b)
    for line in problems:
        print(line)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
