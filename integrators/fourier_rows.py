"""Rows and texels of ``fourier_filter`` on small images.

Baran's slice bound (§8: every pixel centre within half a pixel of a slice)
and the light-ray count (the image diagonal) are stated in pixels.  A camera
sample is answered on its nearest slice's plane with that slice's blockers,
so on an image of a few pixels "half a pixel" is a large angle: the sample
reads the shadows of a plane far from its own ray (1×1: half the field of
view), and a few dozen light rays resolve the shadows along a ray that
crosses the whole scene.  The rows and texels are therefore chosen for an
image of at least ``MIN_IMAGE_SIDE`` pixels on its long side: the slice
spacing shrinks, and the light rays grow, by the same factor.  Only slices
that hold a sample become rows, so a tiny image still has as many rows as
samples at most; the cost is texels per row.
"""
from __future__ import annotations

#: the rectification of an image is at least as fine as for this long side [px]
MIN_IMAGE_SIDE = 32


def small_image_scale(width: int, height: int) -> float:
    """The factor ≤ 1 by which a small image's slice spacing shrinks
    (1 for images of at least ``MIN_IMAGE_SIDE`` pixels on the long side)."""
    return min(1.0, max(int(width), int(height), 1) / MIN_IMAGE_SIDE)


def row_spacing(spacing: float, width: int, height: int) -> float:
    """Slice spacing [px] for the automatic (sinh) slices of a width × height image."""
    return float(spacing) * small_image_scale(width, height)


def rectified_size(width: int, height: int) -> tuple[float, float]:
    """(width, height) [px] the light-ray count is chosen for."""
    s = small_image_scale(width, height)
    return width / s, height / s
