"""Partial renders of the epipolar methods by rows (slices): temporal reuse
(Lin et al.) at the granularity of Baran's slices (§3, §8).

The rows, the light-ray count and the separated kernel of an epipolar
render are chosen from the whole frame (every query); the blockers, the
sweep and the per-query terms of a row depend on that row alone.  A partial
render therefore

1. rectifies the whole frame (:func:`~integrators.epipolar.queries.assign_queries`
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

from ..core.host_reads import row_extremes
from ..core.light_transport import scalar
from ..epipolar.kernel.local import query_x
from ..epipolar.light_factor import lowest_light_side
from ..epipolar.queries import EpipolarQueries, end_gamma


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

    @property
    def whole_frame(self) -> EpipolarQueries:
        return self.whole


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


def _row_lanes(rows: mi.UInt32, per: int) -> mi.UInt32:
    """Flat indices of the ``per`` entries of each of ``rows``, row by row."""
    j = dr.arange(mi.UInt32, dr.width(rows) * per)
    return dr.gather(mi.UInt32, rows, j // per) * per + j % per


def _gather_rows(x, rows: mi.UInt32, per: int):
    return dr.gather(type(x), x, _row_lanes(rows, per))


def put_rows(x, part, rows: mi.UInt32, per: int):
    """A copy of ``x`` (``per`` entries per row) with the entries of
    ``rows`` replaced by ``part`` (theirs, row by row): a partial render's
    rows merged into the last frame's."""
    out = type(x)(x)
    if dr.width(rows):
        dr.scatter(out, part, _row_lanes(rows, per))
    return out


def take_light_rays(queries: EpipolarQueries, rays):
    """The light rays (:class:`~integrators.epipolar.light_rays.directional.LightRays` or a
    subclass) of the rows of the subset ``queries``: every per-row and
    per-light-ray field gathered, ``row_id`` = the rows' numbers in the
    whole frame."""
    if not isinstance(queries, RowSubset):
        return rays
    values = {f.name: take_rows(queries, getattr(rays, f.name)) for f in fields(rays)
              if f.name not in ("d", "row_id")}
    return replace(rays, **values, row_id=mi.UInt32(queries.rows))


def host_finite_range(x) -> tuple:
    """(smallest, largest) finite value of the evaluated array ``x`` (None,
    None: none), read back as a host copy: no kernel
    (:func:`~integrators.core.host_reads.row_extremes`)."""
    lo, hi = row_extremes(x, finite=True)
    return (lo, hi) if lo <= hi else (None, None)


def frame_choices(queries: EpipolarQueries, rays) -> tuple:
    """What the frame-wide choices of an epipolar render are made from, equal
    for two frames whose choices are equal: the rows (count and slices, whose
    numbering keys the sub-rays' jitter), the light-ray count ``d``, whether
    samples are shared by two slices (the adaptive sub-rays' threshold,
    :func:`~integrators.epipolar.blockers._smooth_intervals`), and the inputs of
    the separated kernel's SVD grid, tolerance and tables
    (:func:`~integrators.epipolar.kernel.separation.separated_kernel`,
    :func:`~integrators.epipolar.kernel.local.local_separated_kernel`): the
    queries' β range, the largest γ of the light rays, and the light-side
    gain's lowest path (:func:`~integrators.epipolar.light_factor.light_side_gains`,
    clipped at 0 as it is); for point/spot lights also the lattice (its
    spacing, first cell and size) and the largest tan(β/2)·tan(γ_end/2).
    Everything else a row uses is its own.  Equal summaries mean equal
    choices; the caller renders a frame whose summary changed in full."""
    def low(m):
        return None if m is None else min(m, 0.0)

    def neg(m):
        return None if m is None else -m
    local = getattr(rays, "r_in", None) is not None
    # the light side as the SVD's tolerance reads it (one kernel, shared);
    # the rest are host copies of evaluated arrays (no kernel)
    beta = host_finite_range(queries.beta)
    gamma_max = host_finite_range(rays.gamma_max)
    if local:
        lowest = lowest_light_side(queries, rays,
                                   scalar(queries.frame.light_distance) - rays.r_in)
        mins = [beta[0], neg(beta[1]), neg(gamma_max[1]),
                neg(host_finite_range(rays.delta_gamma)[1]), host_finite_range(rays.gamma_lo)[0],
                neg(host_finite_range(query_x(queries))[1]), lowest]
    else:
        mins = [beta[0], neg(beta[1]), neg(gamma_max[1]),
                lowest_light_side(queries, rays, rays.h)]
    rows = int(np.asarray(queries.slice_index, np.uint64).sum()) if queries.n else 0
    out = [("rows", queries.n, rows),
           ("d", rays.d), ("shared", math.ceil(queries.shares - 1e-6)),
           ("beta", mins[0], neg(mins[1])),
           ("gamma_max", neg(mins[2]))]
    if local:
        out += [("lattice", neg(mins[3]), mins[4], int(dr.max(rays.offset)[0])),
                ("x_max", neg(mins[5])),
                ("light_side", low(mins[6]))]
    else:
        out += [("light_side", low(mins[3]))]
    return tuple(out)


# -- the last frame's rectification ----------------------------------------------------

@dataclass(frozen=True, eq=False)
class Rectification:
    """A frame's queries and what they were made from: which samples had a
    medium segment (``d > 0``), the ring and interpolation settings."""
    queries: EpipolarQueries
    valid: mi.Bool
    ring_degrees: float
    interpolate: bool

    @staticmethod
    def of(queries, cap, ring_degrees: float, interpolate: bool) -> "Rectification":
        # left unevaluated: a kernel only if the next frame compares it
        return Rectification(queries, cap.d > 0, float(ring_degrees), bool(interpolate))


def same_slices(a, b) -> bool:
    """Whether two :class:`~rectify.Slices` are the same slices (count and α)."""
    return (a.count == b.count and np.array_equal(np.asarray(a.alpha), np.asarray(b.alpha)))


def reuse_rectification(params, given, frame, slices, cap, ring_degrees: float,
                        interpolate: bool) -> EpipolarQueries | None:
    """The queries :func:`~integrators.epipolar.queries.assign_queries` would
    make for ``cap``, from an earlier frame's :class:`Rectification`
    ``given``, or None where it does not hold.  Which slice a sample goes
    to, its β, its place in the sweep order (slice, β), the ring and
    ``t_near`` depend on its ray alone; ``d`` only decides whether it is a
    query at all (``d > 0``) and sets its end point.  So where the camera,
    the light (same frame axis and slices) and every sample's ``d > 0``
    are unchanged the earlier queries hold with ``γ_end`` recomputed from
    the new ``d`` (the same expression, so the same values)."""
    if not isinstance(given, Rectification):
        return None
    q = given.queries
    if (given.ring_degrees != float(ring_degrees) or given.interpolate != bool(interpolate)
            or q.n_samples != dr.width(cap.d)
            or not np.array_equal(np.asarray(q.frame.axis), np.asarray(frame.axis))
            or not np.array_equal(np.asarray(q.frame.camera.origin),
                                  np.asarray(frame.camera.origin))
            or not same_slices(q.slices, slices)
            or dr.any(given.valid != (cap.d > 0))[0]):
        return None
    if not q.n:
        return replace(q, frame=frame, slices=slices)
    gamma_end = end_gamma(frame, q.beta, q.t_near + dr.gather(mi.Float, cap.d, q.sample))
    dr.eval(gamma_end)
    return replace(q, frame=frame, slices=slices, gamma_end=gamma_end)


# -- which slices can see what moved --------------------------------------------------

def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n, 8, 3) corners of boxes ``[lo, hi]``."""
    k = np.arange(8)
    bits = np.stack([(k >> i) & 1 for i in range(3)], axis=1).astype(bool)   # (8, 3)
    return np.where(bits[None], hi[:, None, :], lo[:, None, :])


def slice_arcs(frame, boxes) -> list | None:
    """The slices (α ranges) whose half-plane meets one of ``boxes``
    (:class:`~integrators.core.shadow_volumes.Boxes`): a list of arcs ``(start,
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


def slice_meets_boxes_reference(frame, alpha: float, boxes, samples: int = 200) -> bool:
    """Slow NumPy twin of :func:`slice_arcs` for one slice: does the
    half-plane α (the points ``eye + u·axis + γ·e(α)``, γ ≥ 0, e(α) =
    cos α·b1 + sin α·b2) meet a box?  A dense (u, γ) grid over the boxes'
    reach, each point tested against every box (misses intersections
    thinner than the grid spacing)."""
    eye = np.asarray(frame.camera.origin, np.float64)
    axis = np.asarray(frame.axis, np.float64)
    e = np.cos(alpha) * np.asarray(frame.b1) + np.sin(alpha) * np.asarray(frame.b2)
    lo, hi = np.asarray(boxes.lo, np.float64), np.asarray(boxes.hi, np.float64)
    reach = float(np.max(np.linalg.norm(np.concatenate([lo, hi]) - eye, axis=1)))
    u = np.linspace(-reach, reach, samples)
    g = np.linspace(0.0, reach, samples)
    p = eye + u[:, None, None] * axis + g[None, :, None] * e            # (u, γ, 3)
    p = p.reshape(-1, 3)
    for b_lo, b_hi in zip(lo, hi):
        if np.any(np.all((p >= b_lo) & (p <= b_hi), axis=1)):
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


def moved_slices(frame, alpha, moved) -> np.ndarray:
    """Which slices (their α, NumPy) have a half-plane meeting a box of
    ``moved`` (None: nothing moved)."""
    alpha = np.asarray(alpha, np.float64)
    if moved is None or not len(moved) or not alpha.size:
        return np.zeros(alpha.shape, bool)
    return in_arcs(alpha, slice_arcs(frame, moved))


def moved_rows(queries: EpipolarQueries, moved) -> mi.Bool | None:
    """Rows whose slice half-plane meets a box of ``moved`` (None: none)."""
    if moved is None or not len(moved) or not queries.n:
        return None
    return mi.Bool(moved_slices(queries.frame, np.asarray(queries.alpha), moved))
