"""The scattering stage against the captures it needs, at the integrators'
defaults, per suite scene: how far an epipolar method's own work sits above
the floor no scattering method goes below (the camera G-buffer and the
light's visibility capture).

Per scene and method, in one process: the first render (compiles or loads
the kernels), a new frame (the camera moved 5 cm along its x axis, changed
in place as an animation does), then the median of ``--repeats`` warm
renders of that frame, with the median of each stage of
``RenderResult.timings``.  ``captures`` = the camera capture + the
visibility capture inside the scattering stage (blocker map or shadow map,
:data:`episcatter.frontier.VISIBILITY_STAGES`); ``net`` = the scattering
stage minus that visibility capture; ``net / captures`` is the ratio the
capture-floor target bounds by 1.

Writes ``results/capture_floor/``: ``runs.csv``, ``runs.json``, ``table.md``.
``python -m experiments.capture_floor [--size 1280x960] [--scenes ...]
[--methods ...] [--quick]``.
"""
from __future__ import annotations

import statistics
import sys
import time

from . import common as c


NAME = "capture_floor"
SCENES = ["beam", "grove", "hall", "nave_offscreen", "nave_onscreen", "point_fog", "spot_room",
          "sun_ahead", "sun_behind", "sun_room", "terrain"]
QUICK_SCENES = ["point_fog"]
METHODS = ["epipolar_tree"]


def settings_for(quick: bool) -> dict:
    return {"width": 48, "height": 36} if quick else {"width": 1280, "height": 960}


def _render(scene, integ):
    from episcatter.bench import render_with_stages
    t0 = time.perf_counter()
    _, stages = render_with_stages(scene, integ, spp=1)
    return time.perf_counter() - t0, stages


def measure_scene(name: str, s: dict, repeats: int, progress: bool) -> list[dict]:
    import random

    import mitsuba as mi

    from episcatter.flythrough import Motion, animated_keys, apply_change
    from episcatter.frontier import capture_times

    rows = []
    for kind in METHODS:
        scene = c.load(c.scene_file(name), c.resolution(s["width"], s["height"]))
        integ = c.build(kind, {})
        first_s, _ = _render(scene, integ)
        params = mi.traverse(scene)
        apply_change(params, animated_keys(scene, params), "camera", Motion(), random.Random(0))
        params.update()
        new_s, _ = _render(scene, integ)
        runs = [_render(scene, integ) for _ in range(max(int(repeats), 1))]
        stages = {k: statistics.median(r[1][k] for r in runs)
                  for k in runs[0][1] if all(k in r[1] for r in runs)}
        caps = capture_times(stages)
        warm = statistics.median(r[0] for r in runs)
        rows.append({"scene": name, "method": kind, "width": s["width"], "height": s["height"],
                     "first_s": first_s, "new_frame_s": new_s, "warm_s": warm,
                     **caps, "net_over_captures": caps["scattering_net_s"] / caps["captures_s"],
                     "stages": stages})
        if progress:
            r = rows[-1]
            print(f"  {name} {kind}: first {first_s:.2f} s, new frame {new_s:.2f} s, warm "
                  f"{warm:.2f} s; captures {r['captures_s']:.3f} s, net scattering "
                  f"{r['scattering_net_s']:.3f} s ({r['net_over_captures']:.2f}x)", flush=True)
    return rows


def report(rows: list[dict], s: dict, repeats: int) -> str:
    head = (f"# Scattering against the captures, {s['width']}x{s['height']}, defaults, 1 spp\n\n"
            f"Times in seconds; warm = median of {repeats}; stages are medians of the warm "
            "renders.  captures = camera capture + visibility capture (blocker or shadow "
            "map); net = scattering stage - visibility capture.\n\n")
    table = [[r["scene"], r["method"], f"{r['first_s']:.2f}", f"{r['new_frame_s']:.2f}",
              f"{r['warm_s']:.2f}", f"{r['camera_capture_s']:.3f}",
              f"{r['visibility_capture_s']:.3f}", f"{r['scattering_net_s']:.3f}",
              f"{r['net_over_captures']:.2f}"] for r in rows]
    return head + c.markdown_table(["scene", "method", "first", "new frame", "warm", "camera capture",
                                    "visibility capture", "net scattering", "net / captures"],
                                   table)


def main(argv=None) -> list[dict]:
    return c.run_table_experiment(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
