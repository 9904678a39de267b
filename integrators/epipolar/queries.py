"""Queries of the rectified maps: every camera sample outside the epipole
ring is a query of its nearest epipolar slice, sorted by (slice, β) into
rows (Baran et al. 2010 §5, Fig. 6; DESIGN §3).
"""
from __future__ import annotations

import math
import weakref
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify.coords import direction_to_alpha_beta, view_to_light
from rectify.epipole import EpipolarFrame
from rectify.slices import Slices, alpha_to_slice

from ..core.capture import CameraCapture
from ..core.device_sort import argsort_keys
from ..core.light_transport import point
from ..core.opaque import floats, opaque_scalar, uints
from .frame import PAD_BETA, in_ring


# --------------------------------------------------------------------------
# Queries: camera samples sorted into the slices' sweeps (§4)
# --------------------------------------------------------------------------

@dataclass(eq=False)
class EpipolarQueries:
    """Camera samples as queries of their nearest slice's sweep (:mod:`integrators.epipolar`, "Queries").

    Row arrays have ``n`` entries, query arrays ``Q`` (sorted by row, then β);
    ``ring_sample`` lists the camera samples to ray-march instead."""
    frame: EpipolarFrame
    slices: Slices
    n: int                     # rows = slices with queries
    r: int                     # padded queries per row
    slice_index: mi.UInt32     # (n,) index into ``slices``
    alpha: mi.Float            # (n,) α of each row's slice
    r_count: mi.UInt32         # (n,) queries per row
    sample: mi.UInt32          # (Q,) camera sample of each query
    row: mi.UInt32             # (Q,)
    col: mi.UInt32             # (Q,) position in the row's sweep
    beta: mi.Float             # (Q,) the query's own β
    gamma_end: mi.Float        # (Q,) γ of the end point: t_end·sin β (point/spot: angle)
    t_near: mi.Float           # (Q,) pinhole -> camera ray origin
    ring_sample: mi.UInt32     # (R,) camera samples inside the ring
    n_samples: int
    weight: mi.Float | None = None   # (Q,) share of its sample (slice interpolation); None: 1
    shares: float = 1.0        # queries per (non-ring) sample: 1, up to 2 with interpolation

    @property
    def count(self) -> int:
        return dr.width(self.sample) if self.n else 0

    @property
    def whole_frame(self) -> "EpipolarQueries":
        """The queries of the whole frame these belong to, on which frame-wide
        choices are made: themselves (a partial render's
        :class:`~integrators.partial.row_subset.RowSubset`: the frame's)."""
        return self

    @property
    def slot(self) -> mi.UInt32:
        """Flat index ``row·r + col`` of each query in (n, r) maps."""
        return self.row * opaque_scalar(mi.UInt32, self.r) + self.col

    def slot_of(self, q: mi.UInt32) -> mi.UInt32:
        """:attr:`slot` of the queries ``q``, computed where it is read (a
        gather from :attr:`slot` would evaluate it: a kernel of its own)."""
        return (dr.gather(mi.UInt32, self.row, q) * opaque_scalar(mi.UInt32, self.r)
                + dr.gather(mi.UInt32, self.col, q))

    def padded(self, values, fill: float) -> mi.Float:
        """(n·r,) map with the queries' ``values`` in their slots, ``fill`` elsewhere."""
        out = dr.full(mi.Float, fill, self.n * self.r)
        dr.scatter(out, values, self.slot)
        return out


def _nearest_slice(slices: Slices, alpha) -> mi.UInt32:
    k0, k1, f = alpha_to_slice(slices, alpha)
    return dr.select(f < 0.5, k0, k1)


#: slice interpolation: a sample within this fraction of the spacing of a
#: slice is a query of that slice alone
SNAP = 1e-3


def _slice_shares(slices: Slices, alpha, idx: mi.UInt32, used: mi.Bool):
    """(sample, slice, weight) of the queries of samples ``idx`` when each
    is shared between its two neighbouring slices, weights 1 − f and f
    (:func:`~rectify.slices.alpha_to_slice`).  Only slices that are some
    sample's nearest (*used* slices) take shares: where the sinh placement
    (§8) puts slices closer than the pixels (toward the epipole) the others
    would add rows of their own for little, and the nearest slice is there
    well within half a pixel.  So a sample one of whose neighbours is
    nobody's nearest, or within ``SNAP`` of a slice, takes its nearest
    slice's answer alone (weight 1).  Such a *lone* sample (not snapped)
    also asks the used slice on its far side, with weight 0, so that
    :func:`~integrators.epipolar.ring.disagreeing_samples` sees a shadow edge passing between the
    sample and its nearest slice (the beam's edge 0.05 px from a pixel
    centre at 24×18, where the nearest slice was lit and the pixel centre's
    ray is not)."""
    a = dr.gather(mi.Float, alpha, idx)
    k0, k1, f = alpha_to_slice(slices, a)
    nearest = dr.select(f < 0.5, k0, k1)
    both = dr.gather(mi.Bool, used, k0) & dr.gather(mi.Bool, used, k1)
    f = dr.select(both, f, dr.select(f < 0.5, 0.0, 1.0))
    f = dr.select(f < SNAP, 0.0, dr.select(f > 1.0 - SNAP, 1.0, f))
    # the parts in order: k0's shares, k1's shares, the lone samples' far sides
    masks, slice_of = [f < 1.0, f > 0.0], [k0, k1]
    used_idx = dr.compress(used)
    if dr.width(used_idx) >= 2:
        u = np.asarray(used_idx, np.int64)
        sub = Slices(slices.alpha[u], slices.points[u], slices.wraps, "custom")
        j0, j1, fu = alpha_to_slice(sub, a)
        u0, u1 = dr.gather(mi.UInt32, used_idx, j0), dr.gather(mi.UInt32, used_idx, j1)
        far = dr.select(u0 == nearest, u1, u0)
        masks.append(~both & (far != nearest) & (fu > SNAP) & (fu < 1.0 - SNAP))
        slice_of.append(far)
    dr.schedule(f, *slice_of, *masks[1:])  # one kernel with the first mask's
    parts = [dr.compress(m) for m in masks]
    part, at = _concat_index([dr.width(p) for p in parts])
    i = dr.zeros(mi.UInt32, dr.width(part))
    k = dr.zeros(mi.UInt32, dr.width(part))
    for c, (p, kk) in enumerate(zip(parts, slice_of)):
        if not dr.width(p):
            continue
        mine = part == c
        ic = dr.gather(mi.UInt32, p, at, mine)
        i = dr.select(mine, ic, i)
        k = dr.select(mine, dr.gather(mi.UInt32, kk, ic, mine), k)
    fi = dr.gather(mi.Float, f, i)
    weight = dr.select(part == 0, 1.0 - fi, dr.select(part == 1, fi, 0.0))
    return dr.gather(mi.UInt32, idx, i), k, weight


def _concat_index(widths: list) -> tuple:
    """(part, position in it) of every entry of the concatenation of parts of
    ``widths`` (one kernel reads each part at its own offsets; the offsets
    opaque: they change from frame to frame)."""
    total = sum(widths)
    j = dr.arange(mi.UInt32, total)
    part, at, offset = dr.zeros(mi.UInt32, total), mi.UInt32(j), 0
    for c, w in enumerate(widths[:-1]):
        offset += w
        past = j >= opaque_scalar(mi.UInt32, offset)
        part = dr.select(past, mi.UInt32(c + 1), part)
        at = dr.select(past, j - opaque_scalar(mi.UInt32, offset), at)
    return part, at


#: fewest bits of β in the one-key sort of :func:`_sweep_order`
MIN_BETA_BITS = 20


def _sweep_order(k: mi.UInt32, beta: mi.Float, slice_count: int) -> mi.UInt32:
    """Permutation sorting by (slice k, β) (Fig. 6's sweep order within each
    slice): one sort of the 32-bit key k·2^B + ⌊β/π·(2^B − 1)⌋, B = the bits
    the slice count leaves (≥ ``MIN_BETA_BITS``: β to π/2^20 ≈ 3e-6 rad,
    1/300 of a pixel at 1280×960; queries closer than that may swap, which
    moves a blocker edge by as much); else two stable sorts, exact.  The
    key's sort is :func:`~integrators.core.device_sort.argsort_keys` (two
    kernels, the first with the caller's scheduled arrays)."""
    bits = 32 - max(int(slice_count) - 1, 1).bit_length()
    if bits < MIN_BETA_BITS:
        order = dr.argsort(beta)
        return dr.gather(mi.UInt32, order, argsort_keys(dr.gather(mi.UInt32, k, order)))
    scale = float((1 << bits) - 1) / math.pi
    q = mi.UInt32(dr.clip(beta * scale, 0.0, float((1 << bits) - 1)))
    return argsort_keys((k << bits) | q)


def _slice_counts(slices: Slices, k: mi.UInt32) -> mi.UInt32:
    """Queries per slice (``k``: each query's slice; any order)."""
    counts = dr.zeros(mi.UInt32, slices.count)
    dr.scatter_reduce(dr.ReduceOp.Add, counts, mi.UInt32(1), k)
    return counts


def _rows(slices: Slices, k: mi.UInt32, counts: mi.UInt32):
    """(slice_index, r_count, row, col, widest) of queries already sorted by
    slice ``k`` (``counts``: :func:`_slice_counts`, evaluated): the
    non-empty slices become rows 0..n-1, col = rank in the row; ``widest``
    the most queries of a row.  The per-slice bookkeeping (a few thousand
    entries) is done on the host from one copy of the counts, where a
    compression would read its width back anyway."""
    c = np.asarray(counts, np.uint32)
    used = c > 0
    slice_index = np.flatnonzero(used)
    row_of_slice = uints(np.cumsum(used) - used)              # exclusive
    # a row's first query: the queries of the slices before (empty ones add 0)
    begin = uints(np.cumsum(c, dtype=np.uint64) - c)
    col = dr.arange(mi.UInt32, dr.width(k)) - dr.gather(mi.UInt32, begin, k)
    return (slice_index, uints(c[used]), dr.gather(mi.UInt32, row_of_slice, k), col,
            int(c.max()) if c.size else 0)


def _no_queries(frame, slices, ring_sample, n_samples) -> EpipolarQueries:
    u, f = dr.zeros(mi.UInt32, 0), dr.zeros(mi.Float, 0)
    return EpipolarQueries(frame, slices, 0, 0, u, f, u, u, u, u, f, f, f, ring_sample,
                           n_samples)


def end_gamma(frame: EpipolarFrame, beta, t_end) -> mi.Float:
    """γ of the point at distance ``t_end`` on view ray β: ``t_end·sin β``
    (directional, the distance from the axis, §3), or the angle at the light
    between the light ray through it and the direction light -> eye
    (point/spot, §9)."""
    if frame.is_directional:
        return t_end * dr.sin(beta)
    return view_to_light(frame, 0.0, beta, t_end)[0]


def assign_queries(params, frame: EpipolarFrame, slices: Slices, cap: CameraCapture,
                   ring_deg: float, interpolate: bool = False) -> EpipolarQueries:
    """Sort the camera samples of ``cap`` into the sweeps of their nearest
    slices (module doc), or with ``interpolate`` into both neighbouring
    slices, weighted by the sample's position between them
    (:func:`_slice_shares`; ``weight``); ring samples are listed apart,
    samples with ``d = 0`` are dropped (they scatter nothing).  ``γ_end``:
    :func:`end_gamma` of the light kind of ``frame``."""
    n_samples = dr.width(cap.d)
    alpha, beta = direction_to_alpha_beta(frame, cap.omega)
    ring = in_ring(beta, ring_deg) & (cap.d > 0)
    rest = (cap.d > 0) & ~ring
    # t_near and γ_end are the sample's: made here, in sample order, and
    # gathered once each by the sorted queries (not the ray's origin and
    # length, four gathers in sweep order)
    pinhole = mi.Point3f(point(params.camera.origin))
    t_near_s = dr.norm(mi.Vector3f(cap.o - pinhole))
    gamma_end_s = end_gamma(frame, beta, t_near_s + cap.d)
    dr.schedule(alpha, beta, rest, t_near_s, gamma_end_s)   # one kernel with the ring's mask
    if interpolate:
        # the slices some sample is nearest to (_slice_shares), in that kernel
        used = dr.zeros(mi.Bool, slices.count)
        dr.scatter(used, True, _nearest_slice(slices, alpha), rest)
    ring_sample = dr.compress(ring)
    idx = dr.compress(rest)
    if dr.width(idx) == 0:
        return _no_queries(frame, slices, ring_sample, n_samples)
    weight, n_idx = None, dr.width(idx)
    if interpolate:
        idx, k, weight = _slice_shares(slices, alpha, idx, used)
    else:
        k = dr.gather(mi.UInt32, _nearest_slice(slices, alpha), idx)
    b = dr.gather(mi.Float, beta, idx)
    counts = _slice_counts(slices, k)
    # the queries in sample order, their slices' counts and the sort key: one kernel
    dr.schedule(idx, k, b, *([] if weight is None else [weight]))
    order = _sweep_order(k, b, slices.count)
    sample = dr.gather(mi.UInt32, idx, order)
    k, b = dr.gather(mi.UInt32, k, order), dr.gather(mi.Float, b, order)
    if weight is not None:
        weight = dr.gather(mi.Float, weight, order)
    slice_index, r_count, row, col, widest = _rows(slices, k, counts)
    t_near = dr.gather(mi.Float, t_near_s, sample)
    gamma_end = dr.gather(mi.Float, gamma_end_s, sample)
    alpha_rows = floats(np.asarray(slices.alpha)[slice_index])
    q = EpipolarQueries(frame, slices, len(slice_index), widest,
                        uints(slice_index), alpha_rows, r_count, sample, row, col, b, gamma_end,
                        t_near, ring_sample, n_samples, weight, dr.width(idx) / n_idx)
    # each row's largest γ_end (the light rays' reach), with the queries
    gamma_end_max = dr.zeros(mi.Float, q.n)
    dr.scatter_reduce(dr.ReduceOp.Max, gamma_end_max, q.gamma_end, q.row)
    dr.eval(q.slice_index, q.alpha, q.r_count, q.sample, q.row, q.col, q.beta,
            q.gamma_end, q.t_near, q.ring_sample, gamma_end_max,
            *([] if weight is None else [weight]))
    frame_memo(q, ("row_gamma_end",), lambda: gamma_end_max)
    return q


#: per live queries object: what :func:`frame_memo` made of it
_MEMO = weakref.WeakKeyDictionary()


def frame_memo(queries, key: tuple, make):
    """``make()``, made once per queries object (or light rays) and ``key`` (a tuple of a
    name, numbers, and the objects it was made from, compared by identity
    and held with the value): what several stages of a frame read from the same
    queries -- a map, a frame-wide range -- is then one kernel, not one
    per reader."""
    memo = _MEMO.setdefault(queries, {})
    plain = (str, int, float, bool)
    ids = tuple(k if isinstance(k, plain) else id(k) for k in key)
    hit = memo.get(ids)
    if hit is not None and all(a is b or isinstance(a, plain) for a, b in zip(hit[0], key)):
        return hit[1]
    value = make()
    memo[ids] = (key, value)
    return value


def frame_memo_get(queries, key: tuple):
    """What :func:`frame_memo` made of ``queries`` for ``key``, or None where
    it made nothing (nothing is made here)."""
    memo = _MEMO.get(queries, {})
    plain = (str, int, float, bool)
    hit = memo.get(tuple(k if isinstance(k, plain) else id(k) for k in key))
    if hit is not None and all(a is b or isinstance(a, plain) for a, b in zip(hit[0], key)):
        return hit[1]
    return None


def beta_map(queries) -> mi.Float:
    """``queries.padded(queries.beta, PAD_BETA)``, made once per queries
    object (every search of a frame reads the same map) and scheduled: it
    is evaluated with the next kernel over the queries, or where it is
    first read."""
    def make():
        out = queries.padded(queries.beta, PAD_BETA)
        dr.schedule(out)
        return out
    return frame_memo(queries, ("beta_map",), make)


def row_alpha(queries, s):
    return dr.gather(mi.Float, queries.alpha, s)


def searchsorted_rows(queries: EpipolarQueries, s, x, lo=None, hi=None) -> mi.UInt32:
    """Number of queries of row ``s`` with β ≤ ``x`` (per lane); with
    ``lo``/``hi``: known to lie in [lo, hi] (a per-lane bisection that ends
    at once where lo = hi)."""
    beta_pad = beta_map(queries)
    r = opaque_scalar(mi.UInt32, queries.r)
    base = s * r

    def pred(i):
        inside = i < r
        return inside & (dr.gather(mi.Float, beta_pad, base + dr.minimum(i, r - 1)) <= x)

    if lo is None:      # a bisection over [0, r] (r opaque: dr.binary_search unrolls it)
        lo, hi = dr.zeros(mi.UInt32, dr.width(x)), dr.zeros(mi.UInt32, dr.width(x)) + r

    def body(a, b):
        mid = (a + b) >> 1
        left = pred(mid)
        return dr.select(left, mid + 1, a), dr.select(left, b, mid)

    a, _ = dr.while_loop(state=(mi.UInt32(lo), mi.UInt32(hi)), cond=lambda a, b: a < b,
                         body=body)
    return a


def gather_queries(queries: EpipolarQueries, result: mi.TensorXf) -> mi.Color3f:
    """Each query's entry of an (n, r) or (n, r, C) result as a Color3f."""
    flat = mi.Float(result.array)
    C = result.shape[2] if len(result.shape) == 3 else 1
    slot = queries.slot
    if C == 1:
        v = dr.gather(mi.Float, flat, slot)
        return mi.Color3f(v, v, v)
    return mi.Color3f(*(dr.gather(mi.Float, flat, slot * C + c) for c in range(C)))
