"""Procedural textures of the suite: the "stained glass" a spot light projects."""
from __future__ import annotations

import io

import numpy as np

#: saturated glass colours (sRGB, 0-255)
GLASS_COLOURS = np.array([
    (200, 30, 30), (30, 60, 200), (240, 190, 40), (40, 160, 60),
    (150, 40, 170), (240, 120, 30), (60, 170, 200), (230, 230, 200),
], dtype=np.float64)


def stained_glass(size: int = 128, panes: int = 28, seed: int = 3,
                  lead: float = 0.016) -> np.ndarray:
    """A (size, size, 3) uint8 image: Voronoi panes of coloured glass
    separated by dark lead cames, inside a dark circular frame.

    A pixel is lead where it lies within ``lead`` (in units of the image
    width) of the border between its two nearest panes, or near or outside
    the rim of the inscribed circle.
    """
    rng = np.random.default_rng(seed)
    seeds = rng.random((panes, 2))
    colour_of = rng.integers(0, len(GLASS_COLOURS), panes)
    c = (np.arange(size) + 0.5) / size
    px = np.stack(np.meshgrid(c, c), axis=-1).reshape(-1, 1, 2)
    dist = np.linalg.norm(px - seeds[None], axis=-1)
    order = np.argsort(dist, axis=1)
    d_sorted = np.take_along_axis(dist, order[:, :2], axis=1)
    nearest = order[:, 0]
    img = GLASS_COLOURS[colour_of[nearest]]
    # brightness varies a little from pane to pane, like real glass
    img = img * (0.75 + 0.25 * rng.random(panes))[nearest, None]
    # distance to the bisector of the two nearest seeds = Voronoi edge
    gap = np.linalg.norm(seeds[order[:, 1]] - seeds[order[:, 0]], axis=1)
    to_edge = (d_sorted[:, 1] ** 2 - d_sorted[:, 0] ** 2) / (2 * gap)
    is_lead = to_edge < lead / 2
    r = np.linalg.norm(px[:, 0] - 0.5, axis=-1)
    is_lead |= r > 0.47
    img[is_lead] = 12.0
    return np.clip(img, 0, 255).astype(np.uint8).reshape(size, size, 3)


def png_bytes(image: np.ndarray) -> bytes:
    """Encode an (h, w, 3) uint8 image as PNG (Pillow, no metadata)."""
    from PIL import Image

    buf = io.BytesIO()
    pixels = np.ascontiguousarray(image, dtype=np.uint8)
    Image.fromarray(pixels).save(buf, format="PNG", optimize=False)
    return buf.getvalue()
