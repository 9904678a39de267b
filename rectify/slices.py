"""Epipolar slice placement and the pixel -> slice lookup.

A slice is the half-plane ``alpha`` of Baran et al. 2010 §3.  In the image it
is the half-line from the frame's epipole ``E`` (the anti-epipole when the
light is behind the camera; a line of direction ``-direction`` when ``E`` is at
infinity) through an *end point* on the image border.  Slices are generated
from end points on the **exit edges**: the image edges whose line has ``E`` on
the image side (all four for an on-screen epipole), so an off-screen epipole
only gets slices that cross the screen (Yusov 2013, "Sample generation").

- :func:`uniform_slices`: end points equally spaced (default 1 px) along the
  exit edges (Engelhardt & Dachsbacher 2010; Yusov 2013).
- :func:`sinh_slices`: Baran §8, Eq. 5.  For an exit edge at distance ``h``
  [px] from ``E`` with foot point ``F``, end points ``F + h sinh(k/h) e``
  (``e`` the edge direction, integer ``k``) plus the two corners.  Adjacent
  lines are then 1 px apart at the edge, measured perpendicular to the line
  (Fig. 9), so every point of the image is within half a pixel of a slice line
  (between end points ``P_i, P_j`` the worst point of the border lies
  ``h*tanh(1/(2h)) < 1/2`` px from both lines).  Edges with ``h <= 1/2`` only
  need their corners.  At infinity the same rule gives parallel lines 1 px
  apart.

Slices are sorted by ``alpha`` (float64).  ``wraps`` is true when the epipole
is strictly inside the image: the slices then go all the way round and slice
``S-1`` neighbours slice ``0`` (at ``alpha_0 + 2 pi``).  A pixel's
*fractional slice index* ``s = k + f`` (``0 <= f <= 1``) says it lies between
slices ``k`` and ``k+1`` (mod ``S`` if ``wraps``), at the fraction ``f`` of the
way in ``alpha``; its *position along the slice* is its ``beta``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ._dr import aligned, const, const_u32, floats, opaque_scalar, pixel_centres
from .coords import (alpha_beta_to_pixel, alpha_beta_to_pixel_reference, pixel_to_alpha_beta,
                     pixel_to_alpha_beta_reference)
from .epipole import EpipolarFrame


#: slices whose alpha differ by less than this are one slice [rad] (their
#: lines are within ~1e-5 px of each other on the screen)
ALPHA_MERGE = 1e-9
#: stand-in for "infinitely far" distances along a slice line [px]
FAR_REACH = 1e30


@dataclass(frozen=True, eq=False)
class Slices:
    """A set of epipolar slices (see the module docstring)."""
    alpha: np.ndarray     # (S,) float64, strictly increasing, in (-pi, pi]
    points: np.ndarray    # (S, 2) an end point [px] of each slice on the image border
    wraps: bool           # slice S-1 neighbours slice 0 (alpha_0 + 2 pi)
    method: str           # 'uniform' | 'sinh' | 'custom'

    @property
    def count(self) -> int:
        return int(self.alpha.shape[0])

    def __len__(self) -> int:
        return self.count


# --------------------------------------------------------------------------
# placement
# --------------------------------------------------------------------------


def _edges(width: float, height: float):
    """(P0, P1, outward normal) of the four image edges, clockwise (y down)."""
    W, H = float(width), float(height)
    c = [np.array(p) for p in ((0.0, 0.0), (W, 0.0), (W, H), (0.0, H))]
    normals = [np.array(n) for n in ((0.0, -1.0), (1.0, 0.0), (0.0, 1.0), (-1.0, 0.0))]
    return [(c[i], c[(i + 1) % 4], normals[i]) for i in range(4)]


def exit_edges(frame: EpipolarFrame):
    """(P0, P1, n, h) of the edges whose line has the epipole on the image side;
    h = distance from E to the edge line [px] (inf at infinity)."""
    out = []
    X, Y, Wh = frame.epipole_h
    for P0, P1, n in _edges(frame.width, frame.height):
        if Wh == 0.0:
            # E at +infinity along `direction`: the lines travel along -direction
            if float(n @ frame.direction) < -1e-12:
                out.append((P0, P1, n, math.inf))
        else:
            h = float((P0 - frame.epipole) @ n)
            if h >= -1e-12 * max(1.0, float(np.abs(frame.epipole).max())):
                out.append((P0, P1, n, max(h, 0.0)))
    return out


def uniform_edge_points(P0, P1, spacing):
    length = float(np.linalg.norm(P1 - P0))
    n = max(1, int(math.ceil(length / spacing - 1e-9)))
    s = np.arange(n + 1) / n
    return P0 + s[:, None] * (P1 - P0)


def _sinh_edge_points(frame: EpipolarFrame, P0, P1, n, h, spacing: float = 1.0):
    """Baran Eq. 5 on one edge: x(a) = h sinh(a), a in steps of
    ``spacing``/h (Baran: 1/h, lines at most 1 px apart)."""
    length = float(np.linalg.norm(P1 - P0))
    e = (P1 - P0) / length
    if math.isinf(h):
        # parallel lines: ``spacing`` px apart perpendicular to them
        cosang = abs(float(n @ frame.direction))
        return uniform_edge_points(P0, P1, spacing / cosang)
    if h <= 0.5 * spacing:
        # every point between E and this edge is within spacing/2 of the
        # corner lines (a 1 px spacing: no pixel centre lies there at all);
        # the bound scales with the spacing -- at a small image's fine
        # spacing an edge a fraction of a pixel from E still needs its slices
        return np.stack([P0, P1])
    F = frame.epipole + h * n                        # foot of the perpendicular
    x0, x1 = float((P0 - F) @ e), float((P1 - F) @ e)
    a0, a1 = math.asinh(x0 / h), math.asinh(x1 / h)
    step = spacing / h
    k = np.arange(math.floor(a0 / step) + 1, math.ceil(a1 / step))
    k = k[(k * step > a0) & (k * step < a1)]
    x = h * np.sinh(k * step)
    return np.concatenate([P0[None], F + x[:, None] * e, P1[None]])


def _alpha_of_points(frame: EpipolarFrame, pts: np.ndarray) -> np.ndarray:
    d = frame.camera.direction(pts[:, 0], pts[:, 1])
    return np.arctan2(d @ frame.b2, d @ frame.b1)


def slices_from_points(frame: EpipolarFrame, points, method: str = "custom") -> Slices:
    """Slices through the given image points (sorted by alpha, duplicates and
    points at the epipole dropped)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if frame.epipole_h[2] != 0.0:
        scale = max(1.0, float(np.abs(frame.epipole).max()))
        keep = np.linalg.norm(pts - frame.epipole, axis=1) > 1e-9 * scale
        pts = pts[keep]
    alpha = _alpha_of_points(frame, pts)
    order = np.argsort(alpha, kind="stable")
    alpha, pts = alpha[order], pts[order]
    keep = np.ones(alpha.shape, dtype=bool)
    last = -np.inf
    for i, a in enumerate(alpha):
        if a - last < ALPHA_MERGE:
            keep[i] = False
        else:
            last = a
    if frame.wraps and keep.sum() > 1:
        j = np.flatnonzero(keep)
        if alpha[j[0]] + 2 * np.pi - alpha[j[-1]] < ALPHA_MERGE:
            keep[j[-1]] = False
    return Slices(alpha=alpha[keep], points=pts[keep], wraps=frame.wraps, method=method)


def uniform_slices(frame: EpipolarFrame, spacing: float = 1.0) -> Slices:
    """End points every ``spacing`` px (at most) along the exit edges, corners
    included; ``spacing = 1`` guarantees the half-pixel bound."""
    if not spacing > 0:
        raise ValueError(f"spacing must be > 0, got {spacing}")
    pts = [uniform_edge_points(P0, P1, spacing) for P0, P1, _, _ in exit_edges(frame)]
    return slices_from_points(frame, np.concatenate(pts), method="uniform")


def sinh_slices(frame: EpipolarFrame, spacing: float = 1.0) -> Slices:
    """Baran §8 (Eq. 5) slice distribution: lines at most ``spacing`` px
    apart (1: Baran's half-pixel bound)."""
    if not spacing > 0:
        raise ValueError(f"spacing must be > 0, got {spacing}")
    pts = [_sinh_edge_points(frame, P0, P1, n, h, spacing) for P0, P1, n, h in exit_edges(frame)]
    return slices_from_points(frame, np.concatenate(pts), method="sinh")


def make_slices(frame: EpipolarFrame, method: str = "sinh", **kw) -> Slices:
    if method == "sinh":
        return sinh_slices(frame, **kw)
    if method == "uniform":
        return uniform_slices(frame, **kw)
    raise ValueError(f"unknown slice distribution {method!r}: use 'sinh' or 'uniform'")


# --------------------------------------------------------------------------
# slice lines in the image
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SliceLines:
    """Image half-lines of the slices: points ``P + s u`` with ``s >= -reach``
    (``P`` the end point, ``u`` the unit direction away from the epipole,
    ``reach = |P - E|``, FAR_REACH at infinity); ``normal . x = offset`` is the
    full line."""
    start: np.ndarray     # (2,) E (finite stand-in at infinity)
    points: np.ndarray    # (S, 2)
    u: np.ndarray         # (S, 2)
    reach: np.ndarray     # (S,)
    normal: np.ndarray    # (S, 2)
    offset: np.ndarray    # (S,)


def slice_lines(frame: EpipolarFrame, slices: Slices) -> SliceLines:
    X, Y, Wh = frame.epipole_h
    P = slices.points
    u = Wh * P - np.array([X, Y])                  # = Wh (P - E): exact at infinity
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    if Wh == 0.0:
        reach = np.full(len(P), FAR_REACH)
    else:
        reach = np.minimum(np.linalg.norm(P - frame.epipole, axis=1), FAR_REACH)
    normal = np.stack([-u[:, 1], u[:, 0]], axis=1)
    offset = np.einsum("ij,ij->i", normal, P)
    return SliceLines(start=frame.epipole.copy(), points=P, u=u, reach=reach,
                      normal=normal, offset=offset)


def slice_segments(frame: EpipolarFrame, slices: Slices):
    """(entry, exit): the part of each slice's half-line inside the image
    (Liang-Barsky clipping), ordered away from the epipole."""
    L = slice_lines(frame, slices)
    W, H = float(frame.width), float(frame.height)
    lo = -L.reach.copy()
    hi = np.full(len(lo), FAR_REACH)
    for dim, size in ((0, W), (1, H)):
        p, u = L.points[:, dim], L.u[:, dim]
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = (0.0 - p) / u, (size - p) / u
        tmin, tmax = np.minimum(t0, t1), np.maximum(t0, t1)
        par = np.abs(u) < 1e-15
        tmin = np.where(par, -np.inf, tmin)
        tmax = np.where(par, np.inf, tmax)
        lo, hi = np.maximum(lo, tmin), np.minimum(hi, tmax)
    hi = np.maximum(hi, lo)
    return L.points + lo[:, None] * L.u, L.points + hi[:, None] * L.u


# --------------------------------------------------------------------------
# pixel -> slice
# --------------------------------------------------------------------------


def _alpha_table(slices: Slices) -> np.ndarray:
    a = slices.alpha
    return np.append(a, a[0] + 2 * np.pi) if slices.wraps else a


#: lookup bins per table entry of :func:`_first_above`
BINS_PER_SLICE = 8


def _first_above(table_np: np.ndarray, table, alpha) -> mi.UInt32:
    """Per lane, the first i in [0, n − 1) with table[i] > alpha, or n − 1
    (what a binary search over the sorted table gives), found from a
    uniform bin grid over the table's range: each bin stores how many
    entries lie at or below its start (one bin early, so float rounding of
    the bin index cannot overshoot), then a short forward scan."""
    n = len(table_np)
    t32 = np.asarray(table_np, np.float32).astype(np.float64)
    bins = BINS_PER_SLICE * n
    lo, width = t32[0], max((t32[-1] - t32[0]) / bins, 1e-30)
    starts = lo + width * np.arange(bins)
    first = np.minimum(np.searchsorted(t32, starts, side="right"), n - 1)
    first = np.concatenate([[0], first[:-1]])               # one bin early
    b = mi.UInt32(dr.clip(dr.floor((alpha - const(lo)) * const(1.0 / width)), 0, const(bins - 1)))
    i = dr.gather(mi.UInt32, mi.UInt32(aligned(first, np.uint32)), b)
    last = const_u32(n - 1)

    def more(i):
        return (i < last) & (dr.gather(mi.Float, table, dr.minimum(i, last)) <= alpha)

    i = dr.while_loop(state=(i,), cond=more, body=lambda i: (i + 1,))[0]
    return i


def alpha_to_slice(slices: Slices, alpha):
    """Fractional slice coordinates of angles ``alpha`` (Dr.Jit):
    ``(k0, k1, f)`` with ``alpha`` a fraction ``f`` of the way from slice
    ``k0`` to slice ``k1`` (clamped to the extreme slices if not ``wraps``)."""
    table_np = _alpha_table(slices)
    n = len(table_np)
    alpha = mi.Float(alpha)
    if n < 2:
        zero = dr.zeros(mi.UInt32, dr.width(alpha))
        return zero, zero, dr.zeros(mi.Float, dr.width(alpha))
    table = floats(table_np)
    a0 = dr.gather(mi.Float, table, 0)
    if slices.wraps:
        alpha = dr.select(alpha < a0, alpha + 2 * math.pi, alpha)
    idx = _first_above(table_np, table, alpha)
    k0 = dr.clip(mi.Int32(idx) - 1, 0, opaque_scalar(mi.Int32, n - 2))
    k0 = mi.UInt32(k0)
    k1 = k0 + 1
    t0, t1 = dr.gather(mi.Float, table, k0), dr.gather(mi.Float, table, k1)
    f = dr.clip((alpha - t0) / dr.maximum(t1 - t0, 1e-12), 0.0, 1.0)
    if slices.wraps:
        k1 = dr.select(k1 == const_u32(slices.count), 0, k1)
    return k0, k1, f


def pixel_to_slice(frame: EpipolarFrame, slices: Slices, x=None, y=None):
    """Per pixel (centres of the whole image by default, flat row-major):
    ``(s, beta, k0, k1, f)`` with the fractional slice index ``s = k0 + f``
    and the position along the slice ``beta`` (Dr.Jit)."""
    if x is None:
        x, y = pixel_centres(frame.width, frame.height)
    alpha, beta = pixel_to_alpha_beta(frame, x, y)
    k0, k1, f = alpha_to_slice(slices, alpha)
    return mi.Float(k0) + f, beta, k0, k1, f


def pixel_to_slice_reference(frame: EpipolarFrame, slices: Slices, x=None, y=None):
    """Brute force: for each pixel the slice with the largest alpha not above
    the pixel's and the one with the smallest alpha above it (circularly if
    ``wraps``).  Returns (s, beta, k0, k1, f) as NumPy arrays."""
    if x is None:
        yy, xx = np.mgrid[0:frame.height, 0:frame.width]
        x, y = xx.ravel() + 0.5, yy.ravel() + 0.5
    alpha, beta = pixel_to_alpha_beta_reference(frame, x, y)
    A = slices.alpha
    S = len(A)
    k0 = np.zeros(alpha.shape, dtype=np.int64)
    k1 = np.zeros(alpha.shape, dtype=np.int64)
    f = np.zeros(alpha.shape)
    for i, a in enumerate(alpha):
        diff = a - A
        if slices.wraps:
            below = np.mod(diff, 2 * np.pi)           # how far each slice lies below a
            above = np.mod(-diff, 2 * np.pi)
            above[above == 0] = 2 * np.pi
            k0[i], k1[i] = np.argmin(below), np.argmin(above)
            span = below[k0[i]] + above[k1[i]]
            f[i] = below[k0[i]] / span if span > 0 else 0.0
            if k1[i] == k0[i]:
                f[i] = 0.0
        else:
            lower = np.flatnonzero(diff >= 0)
            upper = np.flatnonzero(diff < 0)
            if len(lower) == 0:
                k0[i] = k1[i] = 0
            elif len(upper) == 0:
                k0[i] = k1[i] = S - 1
            else:
                k0[i], k1[i] = lower[-1], upper[0]
                f[i] = diff[k0[i]] / (A[k1[i]] - A[k0[i]])
    return k0 + f, beta, k0, k1, f


def slice_to_alpha(slices: Slices, s) -> mi.Float:
    """Fractional slice index -> alpha (linear between neighbouring slices,
    across the wrap if ``wraps``); inverse of :func:`alpha_to_slice`."""
    table_np = _alpha_table(slices)
    n_seg = len(table_np) - 1
    s = mi.Float(s)
    if n_seg < 1:
        return dr.zeros(mi.Float, dr.width(s)) + const(table_np[0])
    table = floats(table_np)
    s = dr.clip(s, 0.0, const(n_seg))
    k0 = dr.minimum(mi.UInt32(dr.floor(s)), const_u32(n_seg - 1))
    f = s - mi.Float(k0)
    a = dr.lerp(dr.gather(mi.Float, table, k0), dr.gather(mi.Float, table, k0 + 1), f)
    return dr.select(a > math.pi, a - 2 * math.pi, a)


def slice_to_pixel(frame: EpipolarFrame, slices: Slices, s, beta):
    """(fractional slice index, beta) -> film position (x, y) [px] and the
    forward component z of the view ray (z <= 0: not on the film)."""
    return alpha_beta_to_pixel(frame, slice_to_alpha(slices, s), beta)


def slice_to_pixel_reference(frame: EpipolarFrame, slices: Slices, s, beta):
    table = _alpha_table(slices)
    s = np.clip(np.asarray(s, dtype=np.float64), 0, len(table) - 1)
    alpha = np.interp(s, np.arange(len(table)), table)
    return alpha_beta_to_pixel_reference(frame, alpha, beta)


# --------------------------------------------------------------------------
# pixel -> distance to the nearest slice line
# --------------------------------------------------------------------------


def _halfline_distance(px, py, L: SliceLines, k, gather):
    """Distance from (px, py) to half-line k; ``gather(name, k)`` reads the
    per-slice column ``name`` of :func:`_line_columns` (Dr.Jit or NumPy)."""
    ux, uy, Px, Py, reach = (gather(c, k) for c in ("ux", "uy", "Px", "Py", "reach"))
    along = (px - Px) * ux + (py - Py) * uy + reach      # distance past E
    line = abs_((px - Px) * uy - (py - Py) * ux)
    ex, ey = px - L.start[0], py - L.start[1]
    return where_(along >= 0, line, sqrt_(ex * ex + ey * ey))


def _line_columns(L: SliceLines) -> dict:
    return {"ux": L.u[:, 0], "uy": L.u[:, 1], "Px": L.points[:, 0],
            "Py": L.points[:, 1], "reach": L.reach}


def abs_(v):
    return dr.abs(v) if dr.is_array_v(v) else np.abs(v)


def sqrt_(v):
    return dr.sqrt(v) if dr.is_array_v(v) else np.sqrt(v)


def where_(c, a, b):
    return dr.select(c, a, b) if dr.is_array_v(c) else np.where(c, a, b)


def distance_to_slices(frame: EpipolarFrame, slices: Slices) -> mi.Float:
    """Per pixel centre (flat row-major): distance [px] to the nearer of its
    two neighbouring slice half-lines (Dr.Jit)."""
    L = slice_lines(frame, slices)
    x, y = pixel_centres(frame.width, frame.height)
    _, _, k0, k1, _ = pixel_to_slice(frame, slices, x, y)
    cols = {name: floats(v) for name, v in _line_columns(L).items()}

    def gather(name, k):
        return dr.gather(mi.Float, cols[name], k)

    d0 = _halfline_distance(x, y, L, k0, gather)
    d1 = _halfline_distance(x, y, L, k1, gather)
    return dr.minimum(d0, d1)


def distance_to_slices_reference(frame: EpipolarFrame, slices: Slices,
                                 points: np.ndarray | None = None) -> np.ndarray:
    """Brute force over all pixels and all slices: (H, W) distance [px] of each
    pixel centre to the nearest slice half-line; with ``points`` (N, 2)
    image positions [px] instead (antialiased samples lie anywhere in
    their pixel), (N,) distances."""
    L = slice_lines(frame, slices)
    if points is None:
        yy, xx = np.mgrid[0:frame.height, 0:frame.width]
        px, py = xx.ravel()[:, None] + 0.5, yy.ravel()[:, None] + 0.5
    else:
        pts = np.asarray(points, np.float64).reshape(-1, 2)
        px, py = pts[:, :1], pts[:, 1:]
    k = np.arange(slices.count)[None, :]
    cols = _line_columns(L)
    d = _halfline_distance(px, py, L, k, lambda name, kk: cols[name][kk])
    d = d.min(axis=1)
    return d if points is not None else d.reshape(frame.height, frame.width)


def max_distance_to_slices(frame: EpipolarFrame, slices: Slices,
                           width: int | None = None, height: int | None = None) -> float:
    """Largest distance [px] from any pixel centre to its nearest slice line
    (``width``/``height``, if given, must match the frame's camera)."""
    _check_size(frame, width, height)
    return float(dr.max(distance_to_slices(frame, slices))[0])


def max_distance_to_slices_reference(frame: EpipolarFrame, slices: Slices,
                                     width: int | None = None, height: int | None = None) -> float:
    _check_size(frame, width, height)
    return float(distance_to_slices_reference(frame, slices).max())


def _check_size(frame, width, height):
    if (width is not None and width != frame.width) or (height is not None and height != frame.height):
        raise ValueError(f"image size {width}x{height} differs from the camera's "
                         f"{frame.width}x{frame.height}")
