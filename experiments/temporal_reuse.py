"""Temporal reuse on an animated suite scene, and the hybrid ray marcher's
speedup over the plain one on the suite (issue 15, points 3 and 4).

1. ``nave_swing`` (:func:`scenes.temporal.nave_swing`: ``nave_offscreen``
   with a box swinging like a pendulum through the sun shafts), 1280×960,
   one camera sample per pixel: ``epipolar_tree`` (defaults; per-slice
   reuse) and ``raymarch visibility=exact`` (per-sample reuse), each
   re-rendering every frame against reuse on top of it
   (:mod:`experiments.sequence_runs`: same process, frames alternately,
   two-frame warm-up apart).  Reported: speedup over full re-rendering, the
   recomputed fraction (the share of the screen the object and its shadow
   volumes cover, previous and current frame), every reused frame's
   largest difference from its re-render.  Target: ≥ 3× where the fraction
   is ≤ 20 %.
2. ``march=hybrid`` against ``march=full`` (both exact visibility, same
   steps) on every suite scene, 320×240: the hybrid traces the same rays
   where a ray can be shadowed and skips the rest, so its image equals the
   plain one (max difference reported) and the equal-error speedup is the
   time ratio at equal steps (median of 3 warm runs, interleaved).

Writes ``results/temporal_reuse/``: ``table.md``, ``reuse_summary.csv``,
``reuse_frames.csv``, ``hybrid.csv``, ``temporal_reuse.json``.
``python -m experiments.temporal_reuse [--quick] [--skip-hybrid|--skip-reuse]
[--methods fourier_filter,minmax_epipolar] [--resolution 640x480]``.
"""
from __future__ import annotations

import argparse

import numpy as np

from scenes import catalog
from scenes.temporal import NAVE_SWING_MOTION, write_nave_swing

from . import common as c
from .sequence_runs import paired_sequences, summary

NAME = "temporal_reuse"


def settings_for(quick: bool) -> dict:
    return {"reuse_resolution": [160, 120] if quick else [1280, 960],
            "frames": 3 if quick else 5, "steps": 16 if quick else 64,
            "methods": [["epipolar_tree", {}],
                        ["raymarch", {"visibility": "exact", "march": "full",
                                      "steps": 16 if quick else 64}]],
            "volume_boxes": 8,
            "motion": NAVE_SWING_MOTION,
            "hybrid_resolution": [80, 60] if quick else [320, 240],
            "hybrid_scenes": ["nave_offscreen", "point_fog"] if quick else sorted(catalog.SCENES),
            "hybrid_steps": [32] if quick else [64],
            "repeats": 1 if quick else 3, "convention": "pixel centres, 1 spp"}


def reuse_part(s, out):
    path = str(write_nave_swing())
    summaries, frames = [], []
    for kind, props in s["methods"]:
        print(f"nave_swing, {kind} {props}, {s['reuse_resolution']}, load {c.load_average()}",
              flush=True)
        # 1 spp: the suite scenes' sampler asks for 64
        defines = {**c.resolution(*s["reuse_resolution"]), "spp": 1}
        rows, warm = paired_sequences(path, defines, kind,
                                      props, [s["motion"]], s["frames"], s["volume_boxes"])
        frames += [{"method": kind, **r} for r in rows]
        summaries.append({"method": kind, "props": repr(props), "warmup_pair_s": warm,
                          **summary(rows), "load_average": c.load_average()})
    c.write_csv(out / "reuse_summary.csv", summaries)
    c.write_csv(out / "reuse_frames.csv", frames)
    return summaries, frames


def hybrid_part(s, out):
    rows = []
    for name in s["hybrid_scenes"]:
        scene = c.load(c.scene_file(name), c.resolution(*s["hybrid_resolution"]))
        for steps in s["hybrid_steps"]:
            jobs = {m: c.build("raymarch", {"visibility": "exact", "march": m, "steps": steps})
                    for m in ("full", "hybrid")}
            res = c.time_renders(scene, jobs, repeats=s["repeats"])
            a, b = res["full"], res["hybrid"]
            diff = float(np.max(np.abs(b["image"] - a["image"])) / max(float(a["image"].max()), 1e-30))
            rows.append({"scene": name, "steps": steps, "full_s": a["time_s"],
                         "hybrid_s": b["time_s"], "speedup": a["time_s"] / b["time_s"],
                         "hybrid_shadow_volumes_s": b["stages"].get("shadow_volumes", float("nan")),
                         "max_diff_over_peak": diff, "load_average": c.load_average()})
            print(f"  {name} steps={steps}: full {a['time_s']:.2f} s, hybrid {b['time_s']:.2f} s "
                  f"-> {rows[-1]['speedup']:.2f}x (diff/peak {diff:.1e})", flush=True)
    c.write_csv(out / "hybrid.csv", rows)
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true")
    p.add_argument("--out", default=None)
    p.add_argument("--skip-hybrid", action="store_true")
    p.add_argument("--skip-reuse", action="store_true")
    p.add_argument("--methods", default=None,
                   help="comma-separated integrators to animate with their defaults "
                        "(e.g. fourier_filter,minmax_epipolar; default: epipolar_tree and "
                        "raymarch visibility=exact)")
    p.add_argument("--resolution", default=None, help="WxH of the animation (default 1280x960)")
    args = p.parse_args(argv)
    s = settings_for(args.quick)
    if args.methods:
        s["methods"] = [[kind, {}] for kind in args.methods.split(",")]
    if args.resolution:
        s["reuse_resolution"] = [int(v) for v in args.resolution.lower().split("x")]
    out = c.output_dir(NAME, args.out, args.quick)
    reuse, frames = reuse_part(s, out) if not args.skip_reuse else ([], [])
    hybrid = hybrid_part(s, out) if not args.skip_hybrid else []
    c.write_json(out / f"{NAME}.json", s, reuse, frames=frames, hybrid=hybrid)
    text = [f"Temporal reuse, nave_swing {s['reuse_resolution'][0]}x{s['reuse_resolution'][1]}, "
            f"{s['frames']} frames ({s['convention']})", "",
            c.markdown_table(["method", "full fps", "reuse fps", "speedup (reused frames)",
                              "speedup (all frames)", "mean recomputed", "max diff/peak"],
                             [[r["method"], c.fmt(r["fps_full"]), c.fmt(r["fps_reuse"]),
                               c.fmt(r["speedup_reused_frames"]), c.fmt(r["speedup_all_frames"]),
                               c.fmt(r["mean_recomputed_fraction"]),
                               c.fmt(r["max_diff_over_peak"])] for r in reuse]), "",
            f"Hybrid vs full march (exact visibility, equal steps = equal error), "
            f"{s['hybrid_resolution'][0]}x{s['hybrid_resolution'][1]}", "",
            c.markdown_table(["scene", "steps", "full (s)", "hybrid (s)", "speedup", "max diff/peak"],
                             [[r["scene"], r["steps"], c.fmt(r["full_s"]), c.fmt(r["hybrid_s"]),
                               c.fmt(r["speedup"]), c.fmt(r["max_diff_over_peak"])] for r in hybrid])]
    c.write_text(out / "table.md", "\n".join(text))
    print("\n".join(text))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
