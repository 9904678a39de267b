"""Timing animations with and without temporal reuse (shared by
``temporal_table1`` and ``temporal_reuse``).

:func:`paired_sequences` renders the same animation twice in one process,
frame by frame alternately: once re-rendering every frame (the baseline),
once with reuse (:class:`episcatter.sequence.Sequence`), each on its own
copy of the scene, so machine load hits both alike.  A warm-up (one baseline frame, two
reused frames) runs first (kernel compilation, reported apart).  Every reused frame
is compared with its baseline frame (the largest difference over the peak
goes into the rows).  :func:`fit_cost_model` fits Lin et al.'s average cost
per frame, ``T(n) = (T_background + (n − 1)·T_reused) / n`` (their §4 with
no periodic refresh), to the cumulative means.
"""
from __future__ import annotations

import time

import numpy as np

from episcatter.motion import parse_motion
from episcatter.scene_loading import load_scene, make_integrator
from episcatter.sequence import Sequence


def _pair(scene_path, defines, kind, props, motions, frames, volume_boxes):
    out = []
    for reuse in (False, True):
        scene = load_scene(scene_path, defines, optimize=False)
        integ = make_integrator(kind, props)
        out.append(Sequence(scene, integ, [parse_motion(m) for m in motions], frames=frames,
                            reuse=reuse, volume_boxes=volume_boxes, keep_mask=False))
    return out


def paired_sequences(scene_path, defines, kind, props, motions, frames, volume_boxes=8,
                     progress=True):
    """Rows per frame: baseline and reuse times (s) with their stages,
    recomputed samples, and the reused frame's largest difference from the
    baseline frame over the baseline's peak.  Returns (rows, warmup_s)."""
    t0 = time.perf_counter()
    warm = _pair(scene_path, defines, kind, props, motions, frames, volume_boxes)
    warm[0].render_frame(0)                 # the baseline renders every frame alike
    for k in range(min(2, frames)):         # reuse: a full and a partial frame
        warm[1].render_frame(k)
    warmup_s = time.perf_counter() - t0
    full_seq, reuse_seq = _pair(scene_path, defines, kind, props, motions, frames, volume_boxes)
    rows = []
    for k in range(frames):
        a = full_seq.render_frame(k)
        b = reuse_seq.render_frame(k)
        ref = a.layers["full"]
        diff = float(np.max(np.abs(b.layers["full"] - ref)) / max(float(ref.max()), 1e-30))
        rows.append({"frame": k, "full_s": a.timings["total"], "reuse_s": b.timings["total"],
                     "recomputed": b.recomputed, "samples": b.samples,
                     "recomputed_fraction": b.recomputed_fraction,
                     "whole_frame": ";".join(b.whole_frame), "max_diff_over_peak": diff,
                     **{f"full_{s}_s": v for s, v in a.timings.items() if s != "total"},
                     **{f"reuse_{s}_s": v for s, v in b.timings.items() if s != "total"}})
        if progress:
            print(f"    frame {k}: full {a.timings['total']:.2f} s, reuse {b.timings['total']:.2f} s "
                  f"({b.recomputed_fraction:.3f} recomputed, diff/peak {diff:.1e})", flush=True)
    return rows, warmup_s


def fit_cost_model(times) -> dict:
    """Least-squares fit of ``T(n) = (T_background + (n − 1)·T_reused) / n``
    to the cumulative mean frame times of a reused sequence (n = 1, 2, ...):
    with ``S(n) = n·T(n)`` linear in n, ``S(n) = T_bg + (n − 1)·T_re``."""
    t = np.asarray(times, dtype=np.float64)
    n = np.arange(1, len(t) + 1)
    S = np.cumsum(t)
    A = np.stack([np.ones_like(n, dtype=np.float64), n - 1.0], 1)
    (t_bg, t_re), *_ = np.linalg.lstsq(A, S, rcond=None)
    model = (t_bg + (n - 1) * t_re) / n
    return {"T_background_s": float(t_bg), "T_reused_s": float(t_re),
            "rms_rel_residual": float(np.sqrt(np.mean((model / (S / n) - 1) ** 2)))}


def summary(rows) -> dict:
    """Speedups and fps from :func:`paired_sequences` rows: over all frames
    (frame 0 is a full render in both) and over the reused frames alone."""
    full = np.array([r["full_s"] for r in rows])
    reuse = np.array([r["reuse_s"] for r in rows])
    frac = np.array([r["recomputed_fraction"] for r in rows])
    later = slice(1, None)
    return {
        "frames": len(rows),
        "fps_full": len(full) / full.sum(), "fps_reuse": len(reuse) / reuse.sum(),
        "speedup_all_frames": full.sum() / reuse.sum(),
        "speedup_reused_frames": full[later].sum() / reuse[later].sum() if len(rows) > 1 else float("nan"),
        "median_frame_speedup": float(np.median(full[later] / reuse[later])) if len(rows) > 1 else float("nan"),
        "mean_recomputed_fraction": float(frac[later].mean()) if len(rows) > 1 else 1.0,
        "max_recomputed_fraction": float(frac[later].max()) if len(rows) > 1 else 1.0,
        "max_diff_over_peak": max(r["max_diff_over_peak"] for r in rows),
        **{f"cost_model_{k}": v for k, v in fit_cost_model(reuse).items()},
    }
