"""The epipolar geometry drawn over an image of the scene (what a user
checks first when something looks wrong near the light): slice lines of
Baran's ``sinh`` placement (§8), the epipole and its case, and the ring of
ray-marched pixels around it (§6).  NumPy + matplotlib only."""
from __future__ import annotations

import numpy as np

#: preview integrator when no image is given: a cheap shadow-mapped marcher
PREVIEW = {"type": "raymarch", "steps": 64, "shadowmap_resolution": 512}


def preview_image(scene) -> np.ndarray:
    """A quick 1-spp render of the scene (:data:`PREVIEW`), (H, W, 3)."""
    import mitsuba as mi

    from .reference import render_rgb
    return render_rgb(scene, mi.load_dict(PREVIEW), spp=1)


def display_rgb(rgb: np.ndarray) -> np.ndarray:
    """Auto-exposed, gamma-2.2 RGB in [0, 1] for drawing."""
    from .imageio import auto_exposure_scale

    rgb = np.nan_to_num(np.asarray(rgb, dtype=np.float64)[..., :3], nan=0.0)
    return np.clip(rgb * auto_exposure_scale(rgb), 0.0, 1.0) ** (1 / 2.2)


def every_kth(count: int, at_most: int) -> np.ndarray:
    """Indices of at most ``at_most`` evenly spread slices out of ``count``."""
    if count <= at_most:
        return np.arange(count)
    return np.unique(np.linspace(0, count - 1, at_most).round().astype(int))


def draw_overlay(path, rgb, frame, ring_deg: float, max_lines: int = 48) -> dict:
    """Write a PNG of ``rgb`` with the slices (every k-th of the sinh
    placement, at most ``max_lines``), the epipole (or an arrow toward it
    when it is off the picture) and the ring outline.  Returns what was
    drawn: ``slices`` (total), ``lines``, ``epipole_marked``, ``ring_pixels``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from rectify.ring import ring_mask_reference
    from rectify.slices import sinh_slices, slice_segments

    h, w = rgb.shape[:2]
    slices = sinh_slices(frame)
    entry, exit_ = slice_segments(frame, slices)
    pick = every_kth(slices.count, max_lines)
    fig, ax = plt.subplots(figsize=(8, 8 * h / w + 0.6), dpi=100)
    ax.imshow(display_rgb(rgb), extent=(0, w, h, 0), interpolation="nearest")
    for i in pick:
        ax.plot([entry[i, 0], exit_[i, 0]], [entry[i, 1], exit_[i, 1]], "-", color="cyan",
                lw=0.6, alpha=0.8)
    ring = ring_mask_reference(frame, ring_deg)
    if ring.any():
        ax.contour(np.arange(w) + 0.5, np.arange(h) + 0.5, ring.astype(float), levels=[0.5],
                   colors="red", linewidths=1.0)
    ex, ey = (float(v) for v in frame.epipole)
    marked = bool(np.isfinite([ex, ey]).all() and -0.5 * w <= ex <= 1.5 * w
                  and -0.5 * h <= ey <= 1.5 * h)
    if marked:
        ax.plot([ex], [ey], "x", color="yellow", ms=12, mew=2)
        ax.set_xlim(min(0, ex - 10), max(w, ex + 10))
        ax.set_ylim(max(h, ey + 10), min(0, ey - 10))
    else:
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        toward = np.array([ex - w / 2, ey - h / 2])
        d = toward if np.isfinite(toward).all() else np.asarray(frame.direction, dtype=float)
        if np.isfinite(d).all() and np.linalg.norm(d) > 0:
            d = d / np.linalg.norm(d) * 0.2 * min(w, h)
            ax.annotate("", xy=(w / 2 + d[0], h / 2 + d[1]), xytext=(w / 2, h / 2),
                        arrowprops={"arrowstyle": "->", "color": "yellow", "lw": 2})
    ax.set_title(f"{frame.light_kind} light, epipole ({ex:.1f}, {ey:.1f}) px, {frame.case}; "
                 f"{len(pick)} of {slices.count} sinh slices drawn; ring {ring_deg:g}° "
                 f"({int(ring.sum())} px, red)", fontsize=8)
    ax.set_xlabel("x [px]", fontsize=8)
    ax.set_ylabel("y [px]", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return {"slices": int(slices.count), "lines": int(len(pick)), "epipole_marked": marked,
            "ring_pixels": int(ring.sum())}
