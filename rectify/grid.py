"""The rectified (slice, beta) sample grid.

Values computed in rectified space live on a grid of ``S`` slices (rows, in
the order of :attr:`Slices.alpha`) times ``M`` samples along each slice: sample
``j`` of slice ``k`` is the view ray ``(alpha_k, beta_kj)`` with
``beta_kj = start[k] + j * step[k]``.  Arrays are ``(S, M)`` or ``(S, M, C)``,
row-major (flat index ``(k*M + j)*C + c``).

- :func:`shared_beta_grid`: one beta axis for every slice (Baran §3/§6: "all
  slices have the same geometry"; the methods use sub-ranges of it);
- :func:`per_slice_beta_grid`: each slice's own on-screen beta range (Yusov
  2013: samples between the entry and exit points of each line).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ._dr import const_u32, floats
from .coords import alpha_beta_to_direction, alpha_beta_to_direction_reference
from .epipole import EpipolarFrame
from .slices import Slices, slice_lines, slice_segments


@dataclass(frozen=True, eq=False)
class BetaGrid:
    start: np.ndarray     # (S,) beta of sample 0 [rad]
    step: np.ndarray      # (S,) beta increment between samples [rad], > 0
    count: int            # M >= 2 samples per slice

    def betas(self) -> np.ndarray:
        """(S, M) beta of every grid sample."""
        return self.start[:, None] + np.arange(self.count)[None, :] * self.step[:, None]


def slice_beta_ranges(frame: EpipolarFrame, slices: Slices, margin_px: float = 1.0):
    """(beta_lo, beta_hi) per slice: the beta range of its on-screen segment,
    extended by ``margin_px`` pixels at both ends (never past the epipole)."""
    entry, exit_ = slice_segments(frame, slices)
    L = slice_lines(frame, slices)
    s_entry = np.einsum("ij,ij->i", entry - L.points, L.u)
    s_entry = np.maximum(s_entry - margin_px, -L.reach)
    a = L.points + s_entry[:, None] * L.u
    b = exit_ + margin_px * L.u
    da = frame.camera.direction(a[:, 0], a[:, 1])
    db = frame.camera.direction(b[:, 0], b[:, 1])

    def beta(d):
        c = (d @ frame.axis) / np.linalg.norm(d, axis=1)
        return np.arccos(np.clip(c, -1.0, 1.0))

    ba, bb = beta(da), beta(db)
    return np.minimum(ba, bb), np.maximum(ba, bb)


def pixel_angle(frame: EpipolarFrame) -> float:
    """Angle [rad] subtended by one pixel at the image centre (the largest
    per-pixel angle of a pinhole camera): a beta step that undersamples no
    slice."""
    cam = frame.camera
    return min(2 * float(np.linalg.norm(cam.x_axis)) / cam.width,
               2 * float(np.linalg.norm(cam.y_axis)) / cam.height)


def _grid(lo, hi, count):
    count = max(2, int(count))
    hi = np.maximum(hi, lo + 1e-9)
    return BetaGrid(start=lo.astype(np.float64), step=(hi - lo) / (count - 1), count=count)


def shared_beta_grid(frame: EpipolarFrame, slices: Slices, count: int | None = None,
                     margin_px: float = 1.0) -> BetaGrid:
    """One beta axis spanning every slice's range; ``count`` defaults to one
    sample per pixel angle."""
    lo, hi = slice_beta_ranges(frame, slices, margin_px)
    blo, bhi = float(lo.min()), float(hi.max())
    if count is None:
        count = int(math.ceil((bhi - blo) / pixel_angle(frame))) + 1
    S = slices.count
    return _grid(np.full(S, blo), np.full(S, bhi), count)


def per_slice_beta_grid(frame: EpipolarFrame, slices: Slices, count: int | None = None,
                        margin_px: float = 1.0) -> BetaGrid:
    """Each slice's own beta range (widened to its neighbours') with ``count``
    samples (default: one per pixel of the longest on-screen segment)."""
    lo, hi = slice_beta_ranges(frame, slices, margin_px)
    # a pixel between slices k and k+1 reads both at its own beta: let each
    # slice cover its neighbours' ranges too (short grazing slices otherwise clamp)
    lo = np.minimum(lo, np.minimum(np.roll(lo, 1), np.roll(lo, -1))) if slices.wraps else \
        np.minimum.reduce([lo, np.r_[lo[:1], lo[:-1]], np.r_[lo[1:], lo[-1:]]])
    hi = np.maximum(hi, np.maximum(np.roll(hi, 1), np.roll(hi, -1))) if slices.wraps else \
        np.maximum.reduce([hi, np.r_[hi[:1], hi[:-1]], np.r_[hi[1:], hi[-1:]]])
    if count is None:
        entry, exit_ = slice_segments(frame, slices)
        count = int(math.ceil(np.linalg.norm(exit_ - entry, axis=1).max() + 2 * margin_px)) + 1
    return _grid(lo, hi, count)


def grid_directions_reference(frame: EpipolarFrame, slices: Slices, grid: BetaGrid) -> np.ndarray:
    """(S, M, 3) unit view direction of every grid sample."""
    alpha = np.broadcast_to(slices.alpha[:, None], (slices.count, grid.count))
    return alpha_beta_to_direction_reference(frame, alpha, grid.betas())


def grid_directions(frame: EpipolarFrame, slices: Slices, grid: BetaGrid) -> mi.Vector3f:
    """Unit view directions of the S*M grid samples, flat row-major (Dr.Jit);
    trace ``o + t d`` along them to fill rectified maps such as D[alpha, beta]."""
    idx = dr.arange(mi.UInt32, slices.count * grid.count)
    k = idx // const_u32(grid.count)
    j = idx - k * const_u32(grid.count)
    alpha = dr.gather(mi.Float, floats(slices.alpha), k)
    beta = dr.fma(mi.Float(j), dr.gather(mi.Float, floats(grid.step), k),
                  dr.gather(mi.Float, floats(grid.start), k))
    return alpha_beta_to_direction(frame, alpha, beta)
