"""Cost of a projected spot-light texture in ``epipolar_tree`` (issue point 6;
Baran 2010 §6/§10: a textured light costs about 1.5× the untextured one).

``spot_room`` is rendered as shipped (stained-glass texture) and with its
``<texture>`` element removed, in one process with interleaved rounds
(:func:`experiments.common.time_jobs`); the ratio of the scattering stage
(the method's whole work, camera capture excluded) is reported per
resolution, with the stage split.  ``python -m experiments.spot_texture_cost
[--quick]`` writes ``results/spot_texture_cost/``.
"""
from __future__ import annotations

import argparse
import os
import re

import mitsuba as mi

from experiments import common
from scenes import path as scene_path

TEXTURE = re.compile(r'<texture type="bitmap" name="texture">.*?</texture>', re.S)
STAGES = ("rectify", "blockers", "svd", "sweep", "unrectify", "ring", "scattering")


def spot_scenes(width: int, height: int) -> dict:
    """{'textured': scene, 'untextured': scene} of spot_room at width×height."""
    path = scene_path("spot_room")
    xml = open(path).read()
    plain, n = TEXTURE.subn("", xml)
    if n != 1:
        raise ValueError("spot_room.xml no longer has exactly one bitmap <texture>.")
    cwd = os.getcwd()
    os.chdir(os.path.dirname(path))          # the texture path is relative
    try:
        defines = {"res_x": str(width), "res_y": str(height)}
        return {"textured": mi.load_string(xml, **defines),
                "untextured": mi.load_string(plain, **defines)}
    finally:
        os.chdir(cwd)


def measure(width: int, height: int, repeats: int) -> list[dict]:
    scenes = spot_scenes(width, height)
    jobs = {k: (sc, common.build("epipolar_tree", {"output": "scattering"}))
            for k, sc in scenes.items()}
    with common.limit_blas_threads(1):
        timed = common.time_jobs(jobs, repeats=repeats)
    rows = []
    for label, r in timed.items():
        row = {"resolution": f"{width}x{height}", "light": label, "repeats": repeats}
        row.update({f"{s}_ms": 1e3 * r["stages"].get(s, float("nan")) for s in STAGES})
        rows.append(row)
    ratio = rows[0]["scattering_ms"] / rows[1]["scattering_ms"]
    for row in rows:
        row["textured_over_untextured"] = ratio
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="tiny images, 1 repeat")
    parser.add_argument("--out", help="output folder")
    args = parser.parse_args(argv)
    sizes = [(40, 30)] if args.quick else [(160, 120), (320, 240), (640, 480)]
    repeats = 1 if args.quick else 5
    rows = [row for w, h in sizes for row in measure(w, h, repeats)]
    out = common.output_dir("spot_texture_cost", args.out, args.quick)
    settings = {"scene": "spot_room", "sizes": sizes, "repeats": repeats,
                "load_average": common.load_average()}
    common.write_json(out / "cost.json", settings, rows)
    common.write_csv(out / "cost.csv", rows)
    lines = ["| resolution | light | " + " | ".join(f"{s} [ms]" for s in STAGES) + " | ratio |",
             "|---|---|" + "---|" * (len(STAGES) + 1)]
    for row in rows:
        lines.append(f"| {row['resolution']} | {row['light']} | "
                     + " | ".join(common.fmt(row[f'{s}_ms']) for s in STAGES)
                     + f" | {row['textured_over_untextured']:.2f} |")
    table = "\n".join(lines)
    common.write_text(out / "table.md", f"# spot_texture_cost\n\nload average {settings['load_average']}\n\n{table}\n")
    print(table)


if __name__ == "__main__":
    main()
