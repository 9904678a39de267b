"""Lin et al. Table 1 rerun: the hybrid ray marcher (Wyman & Ramsey 2008)
against temporal reuse on top of it.

Four scenes like the paper's (:func:`scenes.temporal.table1_scene`: one
point light in a box room, one moving object of about 50k, 100k, 250k and
750k triangles, turning a quarter turn over the animation), 1024×1024, one
camera sample per pixel, ``raymarch march=hybrid`` (exact visibility inside
the occluders' bounded shadow volumes).  Per scene the animation runs twice
in one process, frame by frame alternately (:mod:`experiments.sequence_runs`):
re-rendering every frame, and recomputing only the change mask's samples.
Reported: frames per second of both, speedup (the paper: 1.10–1.41×), the
recomputed fraction per frame, every reused frame's largest difference from
the re-rendered one (exactness), and the paper's cost model
``T(n) = (T_background + (n − 1)·T_reused)/n`` fitted to the reused
sequence.  Times are single frames (each frame is a different image), after
a two-frame warm-up pair (compilation) reported apart; ``uptime`` load is
recorded.

Writes ``results/temporal_table1/``: ``table.md``, ``summary.csv``,
``frames.csv``, ``temporal_table1.json``, ``fraction.png``.
``python -m experiments.temporal_table1 [--quick] [--resolution 1024] [--frames 8]``.
"""
from __future__ import annotations

import argparse

from scenes.temporal import TABLE1_MOTION, TABLE1_TRIANGLES, write_table1

from . import common as c
from .sequence_runs import paired_sequences, summary

NAME = "temporal_table1"
PAPER = {"fps_speedup": "1.10-1.41x (dragon, bunny, buddha, yeahRight), reused frame number 3",
         "baseline": "hybrid ray marching (Wyman & Ramsey 2008), GPU"}


def settings_for(quick: bool, resolution: int = 1024, frames: int = 8) -> dict:
    return {"resolution": [64, 64] if quick else [resolution, resolution],
            "frames": 3 if quick else frames,
            "triangles": [50_000] if quick else list(TABLE1_TRIANGLES),
            "integrator": "raymarch",
            "props": {"visibility": "exact", "march": "hybrid", "steps": 64, "volume_boxes": 8},
            "motion": TABLE1_MOTION, "volume_boxes": 8, "convention": "pixel centres, 1 spp"}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true")
    p.add_argument("--out", default=None)
    p.add_argument("--resolution", type=int, default=1024, help="image side (default 1024)")
    p.add_argument("--frames", type=int, default=8)
    args = p.parse_args(argv)
    s = settings_for(args.quick, args.resolution, args.frames)
    out = c.output_dir(NAME, args.out, args.quick)
    defines = {**c.resolution(*s["resolution"]), "spp": 1}   # the scenes' sampler asks for 64
    summaries, frames = [], []
    for path in write_table1(triangles=s["triangles"]):
        n = int(path.stem.split("_")[1])
        print(f"{path.name}: {n} triangles, {s['resolution']}, load {c.load_average()}", flush=True)
        rows, warm = paired_sequences(str(path), defines, s["integrator"], s["props"],
                                      [s["motion"]], s["frames"], s["volume_boxes"])
        frames += [{"triangles": n, **r} for r in rows]
        summaries.append({"triangles": n, "warmup_pair_s": warm, **summary(rows),
                          "load_average": c.load_average()})
    c.write_csv(out / "summary.csv", summaries)
    c.write_csv(out / "frames.csv", frames)
    c.write_json(out / f"{NAME}.json", s, summaries, frames=frames, paper=PAPER)
    table = c.markdown_table(
        ["triangles", "hybrid fps", "reuse fps", "speedup (all frames)", "speedup (reused frames)",
         "mean recomputed", "T_bg (s)", "T_reused (s)", "max diff/peak"],
        [[r["triangles"], c.fmt(r["fps_full"]), c.fmt(r["fps_reuse"]),
          c.fmt(r["speedup_all_frames"]), c.fmt(r["speedup_reused_frames"]),
          c.fmt(r["mean_recomputed_fraction"]), c.fmt(r["cost_model_T_background_s"]),
          c.fmt(r["cost_model_T_reused_s"]), c.fmt(r["max_diff_over_peak"])] for r in summaries])
    c.write_text(out / "table.md", f"Lin et al. Table 1 rerun ({s['resolution'][0]}x"
                 f"{s['resolution'][1]}, {s['frames']} frames, {s['convention']}; paper: "
                 f"{PAPER['fps_speedup']})\n\n{table}")
    plt = c.pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.2))
    for r in summaries:
        fr = [f for f in frames if f["triangles"] == r["triangles"]]
        ax.plot([f["frame"] for f in fr], [f["recomputed_fraction"] for f in fr], "o-",
                label=f"{r['triangles'] // 1000}k")
    ax.set_xlabel("frame")
    ax.set_ylabel("recomputed fraction")
    ax.legend()
    c.savefig(fig, out / "fraction.png")
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
