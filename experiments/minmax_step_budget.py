"""Where the min/max tree march's steps go (issue 14; Yusov 2013, "1D min/max
binary trees", talk "Traversal optimization").

Per scene, ``minmax_epipolar`` at its defaults with the tree on; every march
step is tallied by what it met (:data:`integrators.minmax.minmax_tree.STEP_KINDS`):
nodes taken whole lit or shadowed (above level 0 or at a leaf), nodes shadowed
by their colour state (black), nodes split because their colour is mixed
though the ray is lit there, and nodes split at a genuine shadow boundary.
Reported: mean steps per integration sample of each kind.

``python -m experiments.minmax_step_budget [--size WxH] [--scenes ...]``;
prints a table (nothing written).
"""
from __future__ import annotations

import argparse

import drjit as dr
import numpy as np

from integrators.minmax import integrate as ig
from integrators.minmax import minmax_tree as mt

from . import common as c
from .minmax_tree_gain import scene_path


def tallied_render(scene, integrator) -> dict:
    """Render once with every march tallied; mean steps per sample by kind."""
    totals = dict.fromkeys(mt.STEP_KINDS, 0)
    samples = [0]
    plain = ig.march_tree

    def march(*args, **kw):
        res = plain(*args, **kw, tally=True)
        for k, v in res.tally.items():
            totals[k] += int(dr.sum(v)[0])
        samples[0] += dr.width(res.steps)
        return res

    ig.march_tree = march
    try:
        integrator.render_layers(scene, spp=1)
    finally:
        ig.march_tree = plain
    n = max(samples[0], 1)
    return {k: v / n for k, v in totals.items()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--scenes", nargs="+", default=["spot_room", "spot_room_white"])
    ap.add_argument("--props", default="", help="extra integrator properties k=v,k=v")
    a = ap.parse_args(argv)
    w, h = map(int, a.size.split("x"))
    props = dict(kv.split("=") for kv in a.props.split(",") if kv)
    rows = []
    for name in a.scenes:
        scene = c.load(scene_path(name), c.resolution(w, h))
        t = tallied_render(scene, c.build("minmax_epipolar",
                                          {"small_image_march": False, **props}))
        rows.append([name, c.fmt(sum(t.values()))] + [c.fmt(t[k]) for k in mt.STEP_KINDS])
    text = c.markdown_table(["scene", "steps/sample", *mt.STEP_KINDS], rows)
    print(text + f"\n\n{w}x{h}, mean steps per integration sample by kind.")
    return rows


if __name__ == "__main__":
    main()
