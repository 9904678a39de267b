"""Partial renders of the epipolar methods by rows (slices): temporal reuse
(Lin et al.) at the granularity of Baran's slices (§3, §8).

The rows, the light-ray count and the separated kernel of an epipolar
render are chosen from the whole frame (every query); the blockers, the
sweep and the per-query terms of a row depend on that row alone.  A partial
render therefore

1. rectifies the whole frame (:func:`~integrators.epipolar_setup.assign_queries`
   on the full capture) and makes the frame-wide choices on it (light rays,
   per-light-ray factor, SVD);
2. picks the rows to compute (:func:`dirty_rows`): every row holding a
   masked sample, every row whose light rays can meet what moved (its
   slice's half-plane meets a moved box, :func:`slice_arcs`), and, with
   slice interpolation, the other row of every sample those rows hold;
3. restricts the queries (:func:`restrict_queries`), the light rays and
   every per-row array (:func:`take_rows`) to those rows, keeping each row's
   number in the whole frame (``LightRays.row_id``: its sub-rays keep the
   full render's jitter), and computes them;
4. writes only the samples whose every query lies in a computed row.

The computed samples then equal the full render's (the frame-wide choices
and each row's inputs are the full render's).  Samples outside the widened
mask keep an earlier frame's values only while the frame-wide choices are
unchanged: :func:`frame_choices` summarises them, and the caller
(:mod:`episcatter.sequence`) renders the frame in full when they differ.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify.coords import direction_to_alpha_beta_reference

from .epipolar_setup import EpipolarQueries

#: "no row" in row maps
NO_ROW = 0xFFFFFFFF
#: angular margin [rad] of a moved box's range of slices (float32 α of the slices)
ARC_MARGIN = 1e-5


@dataclass(eq=False)
class RowSubset(EpipolarQueries):
    """Queries of some rows of a frame (:func:`restrict_queries`): ``rows``
    (n,) the rows' numbers in ``whole``, the queries of the whole frame."""
    rows: mi.UInt32 | None = None
    whole: EpipolarQueries | None = None


def whole_queries(queries: EpipolarQueries) -> EpipolarQueries:
    """The queries of the whole frame (``queries`` itself unless a subset):
    the frame-wide choices are made on them."""
    return queries.whole if isinstance(queries, RowSubset) else queries


def restrict_queries(queries: EpipolarQueries, rows: mi.UInt32,
                     ring_sample: mi.UInt32) -> RowSubset:
    """The queries of ``rows`` (sorted row numbers of ``queries``), renumbered
    0..m-1 in that order, same padding ``r``; ``ring_sample``: the ring
    samples to march."""
    m = dr.width(rows)
    new_row = dr.full(mi.UInt32, NO_ROW, queries.n)
    dr.scatter(new_row, dr.arange(mi.UInt32, m), rows)
    keep = dr.compress(dr.gather(mi.UInt32, new_row, queries.row) != NO_ROW) if m else \
        dr.zeros(mi.UInt32, 0)

    def q(v):
        return None if v is None else dr.gather(type(v), v, keep)

    def r(v):
        return dr.gather(type(v), v, rows)
    sub = RowSubset(queries.frame, queries.slices, m, queries.r, r(queries.slice_index),
                    r(queries.alpha), r(queries.r_count), q(queries.sample),
                    dr.gather(mi.UInt32, new_row, q(queries.row)), q(queries.col),
                    q(queries.beta), q(queries.gamma_end), q(queries.t_near), ring_sample,
                    queries.n_samples, q(queries.weight), queries.shares,
                    rows=mi.UInt32(rows), whole=queries)
    dr.eval(sub.slice_index, sub.alpha, sub.r_count, sub.sample, sub.row, sub.col, sub.beta,
            sub.gamma_end, sub.t_near, *([] if sub.weight is None else [sub.weight]))
    return sub


def take_rows(queries: EpipolarQueries, x):
    """``x`` (a per-row array of the whole frame: width n·m for m entries
    per row, or a tensor of shape (n, ...)) at the rows of the subset
    ``queries``; anything else (None, a constant, a tensor shared by all
    rows: shape (1, ...)) unchanged.  For a whole frame: ``x`` itself."""
    if not isinstance(queries, RowSubset) or x is None:
        return x
    n = queries.whole.n
    if isinstance(x, mi.TensorXf):
        if not x.shape or x.shape[0] != n:
            return x
        per = math.prod(x.shape[1:])
        flat = _gather_rows(mi.Float(x.array), queries.rows, per)
        return mi.TensorXf(flat, shape=(queries.n, *x.shape[1:]))
    if not dr.is_array_v(x) or dr.width(x) < n or dr.width(x) % n:
        return x
    return _gather_rows(x, queries.rows, dr.width(x) // n)


def _gather_rows(x, rows: mi.UInt32, per: int):
    j = dr.arange(mi.UInt32, dr.width(rows) * per)
    return dr.gather(type(x), x, dr.gather(mi.UInt32, rows, j // per) * per + j % per)


def take_light_rays(queries: EpipolarQueries, rays):
    """The light rays (:class:`~integrators.epipolar_setup.LightRays` or a
    subclass) of the rows of the subset ``queries``: every per-row and
    per-light-ray field gathered, ``row_id`` = the rows' numbers in the
    whole frame."""
    if not isinstance(queries, RowSubset):
        return rays
    values = {f.name: take_rows(queries, getattr(rays, f.name)) for f in fields(rays)
              if f.name not in ("d", "row_id")}
    return replace(rays, **values, row_id=mi.UInt32(queries.rows))


def _extent(x) -> tuple | None:
    """(min, max) of the finite entries of a Dr.Jit array (None if none)."""
    v = mi.Float(x)
    finite = dr.isfinite(v)
    if not dr.width(v) or not dr.any(finite)[0]:
        return None
    return (float(dr.min(dr.select(finite, v, dr.inf))[0]),
            float(dr.max(dr.select(finite, v, -dr.inf))[0]))


def frame_choices(queries: EpipolarQueries, rays) -> tuple:
    """A summary of the frame-wide choices of an epipolar render, equal for
    two frames whose choices are equal: the rows (count and slices), the
    light-ray count, the extent (min, max) of every field of the light
    rays (row ranges γ, spacings, box exits, lattice offsets) and of the
    queries' β and end points.  The light-ray count, the spot lattice and
    the SVD's sample grid and tolerance are functions of these extents
    (:func:`~integrators.kernel_separation.separated_kernel`,
    :func:`~integrators.epipolar_local_light.local_separated_kernel`), so
    equal summaries mean equal kernels; a change of a row that is not an
    extreme leaves the summary alone (conservative the other way: a frame
    whose summary changed is rendered in full)."""
    out = [("rows", queries.n, int(dr.sum(mi.UInt64(queries.slice_index))[0]) if queries.n else 0),
           ("d", rays.d), ("shared", queries.shares > 1.0)]
    for f in fields(rays):
        v = getattr(rays, f.name)
        if dr.is_array_v(v) and f.name != "row_id":
            out.append((f.name, _extent(v)))
    x = dr.tan(0.5 * queries.beta) * dr.tan(0.5 * queries.gamma_end)
    out += [("beta", _extent(queries.beta)), ("gamma_end", _extent(queries.gamma_end)),
            ("x", _extent(x))]
    return tuple(out)


# -- which slices can see what moved --------------------------------------------------

def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n, 8, 3) corners of boxes ``[lo, hi]``."""
    k = np.arange(8)
    bits = np.stack([(k >> i) & 1 for i in range(3)], axis=1).astype(bool)   # (8, 3)
    return np.where(bits[None], hi[:, None, :], lo[:, None, :])


def slice_arcs(frame, boxes) -> list | None:
    """The slices (α ranges) whose half-plane meets one of ``boxes``
    (:class:`~integrators.change_mask.Boxes`): a list of arcs ``(start,
    length)`` [rad, counter-clockwise], or None when some box surrounds
    the axis (every slice).  A slice's light rays lie in its half-plane
    (the axis and the direction α around it), so a box outside every arc
    meets none of them.  A box projects onto the plane normal to the axis
    as the hull of its corners; seen from the axis it covers the corners'
    α range, the complement of their largest gap, unless that gap is below
    π (the axis passes through the hull: every slice)."""
    if not len(boxes):
        return []
    eye = np.asarray(frame.camera.origin, np.float64)
    corners = _box_corners(np.asarray(boxes.lo, np.float64), np.asarray(boxes.hi, np.float64))
    alpha, _ = direction_to_alpha_beta_reference(frame, corners - eye)
    arcs = []
    for a in np.sort(np.mod(alpha, 2 * np.pi), axis=1):
        gaps = np.diff(np.concatenate([a, a[:1] + 2 * np.pi]))
        g = int(np.argmax(gaps))
        if gaps[g] <= np.pi + 1e-6:
            return None
        start = a[(g + 1) % len(a)]
        arcs.append((float(start), float(2 * np.pi - gaps[g])))
    return arcs


def in_arcs(alpha, arcs: list | None, margin: float = ARC_MARGIN) -> np.ndarray:
    """Whether each α (NumPy) lies in one of ``arcs`` (:func:`slice_arcs`;
    None: all), widened by ``margin`` on both sides."""
    alpha = np.asarray(alpha, np.float64)
    if arcs is None:
        return np.ones(alpha.shape, bool)
    out = np.zeros(alpha.shape, bool)
    for start, length in arcs:
        out |= np.mod(alpha - start + margin, 2 * np.pi) <= length + 2 * margin
    return out


def slice_meets_boxes_reference(frame, alpha: float, boxes, samples: int = 64) -> bool:
    """Slow NumPy twin of :func:`slice_arcs` for one slice: does the
    half-plane α meet a box?  Dense points of every box, each tested by its
    own α (to within the spacing of the points)."""
    eye = np.asarray(frame.camera.origin, np.float64)
    t = (np.arange(samples) + 0.5) / samples
    g = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)
    step = 2 * np.pi / samples
    for lo, hi in zip(np.asarray(boxes.lo), np.asarray(boxes.hi)):
        a, _ = direction_to_alpha_beta_reference(frame, lo + g * (hi - lo) - eye)
        if np.any(np.abs(np.angle(np.exp(1j * (a - alpha)))) < step):
            return True
    return False


# -- the rows of a partial render -------------------------------------------------------

def dirty_rows(queries: EpipolarQueries, mask: mi.Bool, row_moved: mi.Bool | None = None):
    """``(rows, computed)`` of a partial render of ``mask`` (module doc, 2.):
    ``rows`` the sorted row numbers to compute, ``computed`` (mi.Bool over
    the samples) the samples they determine -- ``mask``, and every sample
    with a query in a row holding a masked sample or in a ``row_moved``
    row; ``rows`` also holds the other row of each of those samples."""
    row_dirty = dr.zeros(mi.Bool, queries.n) if row_moved is None else mi.Bool(row_moved)
    if queries.count:
        q_masked = dr.gather(mi.Bool, mask, queries.sample)
        dr.scatter(row_dirty, True, queries.row, q_masked)
    computed = mi.Bool(mask)
    if queries.count:
        dr.scatter(computed, True, queries.sample, dr.gather(mi.Bool, row_dirty, queries.row))
    rows_needed = mi.Bool(row_dirty)
    if queries.count:
        dr.scatter(rows_needed, True, queries.row, dr.gather(mi.Bool, computed, queries.sample))
    dr.eval(computed, rows_needed)
    return dr.compress(rows_needed), computed


def moved_rows(queries: EpipolarQueries, moved) -> mi.Bool | None:
    """Rows whose slice half-plane meets a box of ``moved`` (None: none)."""
    if moved is None or not len(moved) or not queries.n:
        return None
    arcs = slice_arcs(queries.frame, moved)
    return mi.Bool(in_arcs(np.asarray(queries.alpha), arcs))
