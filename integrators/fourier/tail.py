"""The end of each view ray in ``fourier_filter``'s rectified map: the short
run of texels behind its last visibility change, traced on the query's own
ray (beyond Klehm et al. 2014).

A camera sample is a query of its nearest slice (or of both neighbours) at
its own β and depth, but the blockers it reads are those of the *slice's*
plane, up to half a slice spacing from its own ray (Baran §8).  Where the
ray ends on a surface, that surface is also the blocker of the light rays
around the end point (the end point is, or lies behind, the first blocker
of its light ray), so the texels next to the end are where the slice's
plane and the ray's own disagree: in the slice's plane the view ray at β
meets the surface a little before (or after) the query's depth and the
texels in between hold the other side of the surface.  Seen from the
shadowed side -- a point light inside a closed box, the camera outside it
-- the slice's plane puts the inside of the box, lit, on the last texels:
light at the end of a ray that is in shadow all along, with the 1/r² of
fog next to the light (random stress seed 43: 2.3e-3 of the
unoccluded peak with the exact sum).  Seen from the lit side it darkens
the end of the ray.

:func:`tail_visibility` finds, per query, the run of texels behind the last
change of the map's visibility at the query's β, ``V(g, β) = [β ≤ β_b(g)]``,
and where that run is short (at most ``TAIL_TEXELS`` texels, the change not
at the ray's first texel) traces one shadow ray per texel of it from the
middle of the texel's covered part on the query's own camera ray
(:func:`~integrators.core.light_transport.visible_exact`), as a ray marcher
would.  A longer run is a shadow or a lit stretch of the slice itself and
is kept.  The direct sum (:func:`~integrators.fourier.exact.exact_sums`) and
the filter's sums take the traced run instead of the map's visibility
(:meth:`TailVisibility.correction`, :meth:`TailVisibility.delta`).  The epipolar tree's counterpart is
:func:`~integrators.epipolar.last_interval.last_interval_visibility` (one light-ray
interval of four sub-rays; the filter's texels are that interval's
quarters, hence a run of several).

NumPy oracle of the run search: :func:`tail_run_reference`.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.opaque import Divisor, scalar_u32, two_or_more
from ..epipolar.last_interval import own_ray_visibility
from .rectified_map import texel_weight


#: longest run of texels behind the last visibility change that is traced
TAIL_TEXELS = 8
#: a shadow ray starts at least this far [× scene extent] before the
#: surface the view ray ends on
TAIL_EPS = 1e-5
#: no run (the query is not traced)
NO_RUN = 0xFFFFFFFF


@dataclass(eq=False)
class TailVisibility:
    """The traced runs: ``first`` (Q,) the first texel (row-local) of each
    query's traced run, ``NO_RUN`` where none; ``base`` (Q,) its rank among
    the traced queries (its slots of ``V`` start at ``base · slots``; any
    value where none); ``V`` the traced visibility (1/0) of every run texel;
    ``traced``: how many queries were traced."""
    first: mi.UInt32
    base: mi.UInt32
    V: mi.Float
    traced: int
    slots: int = TAIL_TEXELS      # slots of ``V`` per traced query
    idx: mi.UInt32 | None = None  # (traced,) the traced queries

    def subset(self, idx) -> "TailVisibility":
        """The runs of queries ``idx`` (the same traced values)."""
        return TailVisibility(dr.gather(mi.UInt32, self.first, idx),
                              dr.gather(mi.UInt32, self.base, idx), self.V, self.traced,
                              self.slots)

    def correction(self, queries, cover, beta_b, w, layers: int = 1) -> mi.Float:
        """(Q,) Σ over each traced run of w_g c_g (V_traced − V_map): what
        the traced run changes in a weighted sum over the query's texels
        that counted the map's visibility there (``w`` per texel:
        :func:`~integrators.fourier.rectified_map.texel_weight`; ``c_g``
        the covered part).  0 where nothing was traced.  ``layers`` > 1:
        that many weightings ``w(l, texel)`` at once (layer ``l``'s
        corrections at ``l·Q + q``), in one kernel whatever their number."""
        weight = ((lambda t, q: texel_weight(w, t)) if layers == 1
                  else (lambda t, q, l: w(l, t)))
        return self.delta(queries.row, cover.texel, cover.frac, queries.beta, beta_b, cover.d,
                          weight, layers)

    def delta(self, row, texel, frac, beta, beta_b, d: int, weight,
              layers: int = 1) -> mi.Float:
        """:meth:`correction` for queries given by their arrays (row, last
        covered texel ``texel`` (flat), its covered fraction, β; this
        object's ``first``/``base`` are theirs, e.g. a :meth:`subset`) and
        weights ``weight(t, q)`` of flat texels ``t`` for queries ``q``
        (indices into those arrays); ``layers`` > 1: ``weight(t, q, l)``
        of each layer, (layers·Q) out."""
        count = dr.width(beta)
        out = dr.zeros(mi.Float, layers * count)
        if not self.traced:
            return out
        # the arrays read below made in one kernel where they are not yet
        # (a subset's: gathers of the frame's)
        dr.schedule(row, texel, frac, beta, self.first, self.base)
        # the traced queries: kept from the trace (no compression, no read)
        q = self.idx if self.idx is not None else dr.compress(self.runs())
        if not dr.width(q):
            return out
        q = two_or_more(q)          # a single query: summed and written twice
        if layers > 1:              # (layer, traced query) lanes
            layer, i_q = Divisor(dr.width(q)).divmod(dr.arange(mi.UInt32, layers * dr.width(q)))
            q = dr.gather(mi.UInt32, q, i_q)
        row0 = dr.gather(mi.UInt32, row, q) * scalar_u32(d)
        last = dr.gather(mi.UInt32, texel, q)
        f = dr.gather(mi.Float, frac, q)
        b = dr.gather(mi.Float, beta, q)
        first = dr.gather(mi.UInt32, self.first, q)
        base = dr.gather(mi.UInt32, self.base, q) * scalar_u32(self.slots)
        total = dr.zeros(mi.Float, dr.width(q))
        for i in range(self.slots):
            t = row0 + first + i
            on = t <= last
            t = dr.select(on, t, last)
            c = dr.select(t == last, f, 1.0)
            lit = b <= dr.gather(mi.Float, beta_b, t, on)
            traced = dr.gather(mi.Float, self.V, base + i, on)
            delta = traced - dr.select(lit, 1.0, 0.0)
            w = weight(t, q) if layers == 1 else weight(t, q, layer)
            total += dr.select(on, w * c * delta, 0.0)
        dr.scatter(out, total, q if layers == 1 else layer * scalar_u32(count) + q)
        return out

    def runs(self) -> mi.Bool:
        """(Q,) the queries with a traced run."""
        return self.first != NO_RUN


def tail_runs(queries, beta_b, cover, longest: int = TAIL_TEXELS):
    """(first, k0) per query: the first texel (row-local) of the run of
    texels with the visibility of the last covered texel ``k0`` at the
    query's β, searched back at most ``longest + 1`` texels; ``first`` is
    ``NO_RUN`` where the run is longer than ``longest`` or reaches texel 0
    (no change behind the ray's end)."""
    row0 = queries.row * scalar_u32(cover.d)
    k0 = cover.texel - row0
    beta = queries.beta
    last = beta <= dr.gather(mi.Float, beta_b, cover.texel)
    first = mi.UInt32(k0)
    open_run = mi.Bool(True)
    for step in range(1, longest + 2):
        has = open_run & (k0 >= step)
        lit = beta <= dr.gather(mi.Float, beta_b, row0 + k0 - step, has)
        same = has & (lit == last)
        first = dr.select(same, k0 - step, first)
        open_run = same
    changed = (k0 > 0) & (first > 0) & ~open_run & (k0 + 1 - first <= longest)
    return dr.select(changed, first, NO_RUN), k0


def tail_run_reference(beta_b_row, beta: float, k0: int, longest: int = TAIL_TEXELS):
    """NumPy oracle of :func:`tail_runs` for one query: the first texel of
    the run behind the last visibility change, or None."""
    lit = beta <= np.asarray(beta_b_row, np.float64)[:k0 + 1]
    g = k0
    while g > 0 and lit[g - 1] == lit[k0]:
        g -= 1
    if g == 0 or k0 + 1 - g > longest:
        return None
    return g


def tail_visibility(params, cap, queries, rays, beta_b, cover,
                    longest: int = TAIL_TEXELS) -> TailVisibility | None:
    """Trace the short runs behind each query's last visibility change
    (module doc); None for layouts without equal light rays (the
    projective map)."""
    if not rays.equal_widths or not queries.count:
        return None
    first, k0 = tail_runs(queries, beta_b, cover, longest)
    run = first != NO_RUN
    ones = mi.UInt32(run)
    dr.schedule(first, k0, cover.texel, cover.frac, ones)   # with the runs' mask: one kernel
    idx = dr.compress(run)
    traced = dr.width(idx)
    if traced == 0:
        return TailVisibility(first, dr.zeros(mi.UInt32, queries.count),
                              dr.zeros(mi.Float, 1), 0, longest)
    # ``longest`` slots per traced query (its n-th in ``lanes``: slots
    # n·longest ...); a single query is traced twice (two_or_more), into
    # two equal runs, either of which its slot may name
    lanes = two_or_more(idx)
    per = Divisor(longest)          # slots per query (the frame's: opaque)
    # a traced query's rank: its slots follow those of the traced queries before it
    rank = dr.prefix_sum(ones)
    lane = dr.arange(mi.UInt32, dr.width(lanes) * longest)
    run, offset = per.divmod(lane)
    q = dr.gather(mi.UInt32, lanes, run)
    g = dr.gather(mi.UInt32, first, q) + offset
    used = g <= dr.gather(mi.UInt32, k0, q)
    row = dr.gather(mi.UInt32, queries.row, q)
    covered = dr.select(g == dr.gather(mi.UInt32, k0, q), dr.gather(mi.Float, cover.frac, q),
                        1.0)
    gamma = rays.start(row) + (mi.Float(g) + 0.5 * covered) * \
        dr.gather(mi.Float, rays.delta_gamma, row)
    lit = own_ray_visibility(params, cap, queries, q, gamma, TAIL_EPS, active=used)
    V = dr.select(used & lit, 1.0, 0.0)
    dr.eval(V)
    return TailVisibility(first, rank, V, traced, longest, idx)
