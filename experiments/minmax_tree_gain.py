"""What the 1D min/max tree buys (Yusov 2013, "Performance": "without 1D
min/max binary tree acceleration, the ray marching time alone is 3.3 times
higher" for the spot light; coloured shafts: "Ray marching: 1.67 ms ->
5.49 ms", i.e. 3.3× slower than white ones).

Per scene, ``minmax_epipolar`` at its defaults with the tree (``min_max=
true``) and without (``false``: every texel of the slice's height map
visited, the per-texel march); both give the same image (to float32
rounding; checked and listed).  Reported: the median ``integrate`` stage
(the talk's "ray marching"), the mean march steps per integration sample,
their ratios, and coloured against white shafts: the textured spot light of
``spot_room`` against the same scene with the texture removed (target:
coloured ≤ 1.5× white, where the talk's is 3.3×).

Writes ``results/minmax_tree_gain/``: ``runs.csv``, ``runs.json``,
``table.md``.  ``python -m experiments.minmax_tree_gain [--quick]``.
"""
from __future__ import annotations

import numpy as np

from . import common as c
from . import minmax_common as mc

NAME = "minmax_tree_gain"
SCENES = ["spot_room", "spot_room_white", "point_fog", "nave_offscreen", "grove"]
QUICK_SCENES = ["spot_room", "spot_room_white"]
TALK_TREE_GAIN = {"spot_room": 3.3}
TALK_COLOUR_COST = 3.3
TARGET_COLOUR_COST = 1.5


def settings_for(quick: bool) -> dict:
    return {"width": 64, "height": 48} if quick else {"width": 320, "height": 240}


def scene_path(name: str) -> str:
    if name.endswith("_white"):
        return mc.white_spot_scene(c.scene_file(name[: -len("_white")]))
    return c.scene_file(name)


def measure_scene(name, s, repeats) -> list[dict]:
    scene = c.load(scene_path(name), c.resolution(s["width"], s["height"]))
    # the epipolar pipeline at every size (small images would march every pixel)
    integ = {mm: c.build("minmax_epipolar", {"min_max": mm, "small_image_march": False})
             for mm in (True, False)}
    timed = c.time_renders(scene, {f"min_max={k}": v for k, v in integ.items()}, repeats)
    on, off = timed["min_max=True"], timed["min_max=False"]
    rows = []
    for mm, r in ((True, on), (False, off)):
        st = integ[mm].render_layers(scene, spp=1).stats
        rows.append({"scene": name, "min_max": mm, "integrate_ms": 1e3 * r["stages"]["integrate"],
                     "scattering_ms": 1e3 * r["stages"]["scattering"],
                     "mean_steps": st["mean_steps"],
                     "integration_samples": st["integration_samples"],
                     "light_rays": st["settings"]["light_rays"], "load": c.load_average()})
    a, b = np.asarray(on["image"], np.float64), np.asarray(off["image"], np.float64)
    same = float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-30))
    for r in rows:
        r.update(tree_gain_integrate=rows[1]["integrate_ms"] / rows[0]["integrate_ms"],
                 tree_gain_steps=rows[1]["mean_steps"] / rows[0]["mean_steps"],
                 on_off_max_diff_over_peak=same, talk_tree_gain=TALK_TREE_GAIN.get(name))
    return rows


def colour_cost(rows) -> list[dict]:
    """Coloured vs white shafts, tree on and off."""
    out = []
    for mm in (True, False):
        col = [r for r in rows if r["scene"] == "spot_room" and r["min_max"] == mm]
        white = [r for r in rows if r["scene"] == "spot_room_white" and r["min_max"] == mm]
        if col and white:
            out.append({"min_max": mm,
                        "integrate_ratio": col[0]["integrate_ms"] / white[0]["integrate_ms"],
                        "steps_ratio": col[0]["mean_steps"] / white[0]["mean_steps"],
                        "talk": TALK_COLOUR_COST, "target": TARGET_COLOUR_COST})
    return out


def report(rows, cost, s, repeats) -> str:
    header = ["scene", "min/max tree", "integrate ms", "mean steps", "integration samples",
              "tree gain (integrate)", "tree gain (steps)", "talk", "same image (max diff/peak)",
              "load"]
    body = [[r["scene"], r["min_max"], c.fmt(r["integrate_ms"]), c.fmt(r["mean_steps"]),
             r["integration_samples"], c.fmt(r["tree_gain_integrate"]),
             c.fmt(r["tree_gain_steps"]), c.fmt(r["talk_tree_gain"]),
             c.fmt(r["on_off_max_diff_over_peak"]), r["load"][0]] for r in rows]
    text = c.markdown_table(header, body)
    if cost:
        text += "\n\nColoured (textured spot) vs white shafts, integrate stage:\n\n"
        text += c.markdown_table(
            ["min/max tree", "coloured / white (integrate)", "coloured / white (steps)",
             "talk", "target"],
            [[r["min_max"], c.fmt(r["integrate_ratio"]), c.fmt(r["steps_ratio"]),
              r["talk"], f"<= {r['target']}"] for r in cost])
    return text + (f"\n\n{s['width']}x{s['height']}, medians of {repeats} warm runs, "
                   "minmax_epipolar defaults (traced blockers).\n")


def main(argv=None):
    run = c.start_run(__import__(__name__, fromlist=["x"]), argv, SCENES, QUICK_SCENES)
    rows = []
    for name in run.scenes:
        rows += measure_scene(name, run.settings, run.repeats)
        print(f"{name}: done (load {c.load_average()})", flush=True)
    cost = colour_cost(rows)
    text = report(rows, cost, run.settings, run.repeats)
    print(text)
    settings = {"name": NAME, **run.settings, "repeats": run.repeats, "scenes": run.scenes,
                "quick": run.args.quick}
    mc.write_results(run.out, settings, rows, text, colour_cost=cost)
    return rows, cost


if __name__ == "__main__":
    main()
