"""The rectified shadow map of the ``fourier_filter`` method (Klehm et al. 2014, §2.2, §3).

Builds on the epipolar rectification of :mod:`integrators.epipolar.queries`
(queries = camera samples at their own β and depth, ``d`` light rays per
slice, blocker angles β_b per light ray) and feeds the Fourier prefilter of
:mod:`integrators.fourier.basis`.

Rows, texels and depths
-----------------------
Row = epipolar slice α (one row per slice with queries); texel ``g`` = light
ray ``g`` of the row, covering ``γ ∈ γ_lo + [g, g+1)·Δγ`` (γ: the distance
from the camera-light axis for a directional light, ``γ_lo = 0``; the angle
at the light for a point or spot light, Baran §9, ``γ_lo`` the start of a
spot light's cone in the slice).  The depth that is
constant along a view ray is its angle β to the light (Baran's rectification,
Klehm §2.2 "z denotes the angle spanned by the view-ray direction and the
light direction"): view ray β is shadowed on light ray γ iff ``β > β_b(γ)``,
i.e. ``V = 1`` iff ``z_r ≤ z_i``, the shadow test of Eq. 5 with
``z_r = z(β_query)`` and ``z_i = z(β_b(γ_i))`` for any increasing ``z``.

``depth_range`` picks ``z`` (both map into [0, 1] as Eq. 8 requires):

``slice`` (default, beyond the paper)
    Per row, the β range ``[β_lo, β_hi]`` of the row's queries is mapped
    onto ``[0, 1/2]``: ``z = (β − β_lo) / (2 (β_hi − β_lo))``.  Texels whose
    blocker lies outside that range have the same visibility for every
    query of the row: ``β_b ≥ β_hi`` *lit* (nothing, or a blocker behind all
    view rays), ``β_b < β_lo`` *shadowed*.  They are summed exactly (plain
    prefix sums) instead of through the truncated series; only the *series*
    texels, ``β_lo ≤ β_b < β_hi``, are prefiltered.  The half range keeps
    every ``z_r − z_i`` inside ``(−1/2, 1/2]``: no period-2 wrap-around
    (:mod:`integrators.fourier.basis` module doc), and the whole resolution
    of the ``M`` coefficients is spent on the row's own view rays.
``full`` (the straightforward mapping)
    ``z = β / π`` for every texel and query; every texel of a row with any
    blocker in view goes through the series (Eqs. 8-10 as published, with
    the angle range of all possible view rays as the depth range).

Either way, rows with no series texel (nothing blocks inside the view) take
the closed form and skip the filter.  Non-series texels get weight 0 in the
filter and the depth of the row's nearest series texel (so that the
per-region bounds of ``exact_bounds``/``fit_depth`` only see series texels).

Coverage
--------
A query with fractional depth ``D = γ_end/Δγ``
(:func:`~integrators.epipolar.light_rays.layout.rectified_depth`) covers ``clip(D − g, 0, 1)``
of texel ``g`` (:mod:`integrators.tree.partial_sum_tree` convention);
``Σ_g w_g clip(D − g, 0, 1)`` is one exclusive per-row prefix sum plus a
fraction of the next texel (:class:`Coverage`).  In
:func:`~integrators.fourier.prefilter.filtered_visibility`'s texel coordinate
the same coverage is ``j = D − 1`` (texel-centre convention; ``D < 1``
clamps to texel 0, which changes the weight sum, not the average).

Klehm's projective rectification (§4.2) and its texels:
:mod:`integrators.fourier.projective_rays`.

Everything Dr.Jit on the active variant.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.opaque import Divisor, opaque_scalar, scalar_u32, two_or_more
from ..epipolar.light_rays.layout import covered_depth
from ..epipolar.queries import frame_memo
from ..epipolar.query_terms import cell_average
from .prefilter import FilteredBasis, filtered_visibility, prefix_filter, region_depth_bounds


DEPTH_RANGES = ("slice", "full")
REFERENCES = ("bisectrix", "optimal")
#: smallest β range of a row [rad] (rows whose queries share one β)
MIN_SPAN = 1e-7


# --------------------------------------------------------------------------
# Per-row β range of the queries
# --------------------------------------------------------------------------

def query_beta_range(queries):
    """(β_lo, β_hi) per row: the smallest and largest β of its queries,
    made once per frame's queries (the map, the references and the sums
    read them) and scheduled: evaluated with the next kernel over the
    queries (the filter asks for them before its coverage's), or where
    first read."""
    def make():
        lo = dr.full(mi.Float, dr.inf, queries.n)
        hi = dr.full(mi.Float, -dr.inf, queries.n)
        dr.scatter_reduce(dr.ReduceOp.Min, lo, queries.beta, queries.row)
        dr.scatter_reduce(dr.ReduceOp.Max, hi, queries.beta, queries.row)
        dr.schedule(lo, hi)
        return lo, hi
    return frame_memo(queries, ("query_beta_range",), make)


def reference_angle(beta_lo, beta_hi, how: str = "bisectrix"):
    """β_ref per row: the reference ray of Klehm §3.2.

    Klehm picks the reference between the rays of smallest and largest
    optical step per texel, ω_min and ω_max.  The paper's step
    ``Δ = Δ_⊥ / k``, ``k = sin β``, counts the camera side only; here the
    weight of light ray γ also holds the light-side transmittance
    (DESIGN §1), the per-texel optical depth is ``σt Δγ tan(β/2)``, which
    grows with β: ω_min and ω_max are the row's smallest and largest β.

    ``bisectrix`` (the paper's general choice): ``(β_lo + β_hi)/2``.
    ``optimal``: the paper's min-max argument (the worst ratio of the
    reference's step to any ray's, both ways) applied to this rate:
    ``tan(β_ref/2) = √(tan(β_lo/2) tan(β_hi/2))``.  It exists unless a view
    ray is parallel to the light (rate 0 or ∞; excluded by the ring), else
    the bisectrix is used.  For a point or spot light the per-texel optical
    depth ``σt Δγ ∂(t + r)/∂γ = σt L Δγ tan(β/2) (1 + tan²(γ/2)) / (1 − x)²``
    (``x = tan(β/2) tan(γ/2)``) is the same rate ``tan(β/2)`` next to the
    eye (``x → 0``), where the transmittance decays fastest; the same
    reference serves.
    """
    bisectrix = 0.5 * (beta_lo + beta_hi)
    if how == "bisectrix":
        return bisectrix
    x = dr.sqrt(dr.tan(0.5 * beta_lo) * dr.tan(0.5 * beta_hi))
    ok = (beta_lo > 0.0) & (beta_hi < math.pi) & dr.isfinite(x)
    return dr.select(ok, 2.0 * dr.atan(x), bisectrix)


# --------------------------------------------------------------------------
# The rectified shadow map
# --------------------------------------------------------------------------

@dataclass(eq=False)
class RectifiedShadowMap:
    """Depths and texel classes of the rows (module doc); (n·d) texel arrays
    in (row, light ray) order, (Q,) query arrays.  ``z_r`` may be left
    unevaluated (made where it is read: the filter's lookups)."""
    n: int
    d: int
    z: mi.Float          # (n·d) texel depth z_i seen by the filter (see ``z_fill``)
    series: mi.Bool      # (n·d) texel goes through the Fourier series
    lit: mi.Bool         # (n·d) texel lit for every query of its row (exact)
    z_r: mi.Float        # (Q,) query depth
    filtered: mi.Bool    # (n,) row has series texels
    rows: mi.UInt32      # (nf,) the filtered rows
    frow: mi.UInt32      # (n,) index of a filtered row in ``rows``
    #: (n,) None, or each row's smallest series depth (inf if none): then
    #: ``z`` holds the series texels' depths and a non-series texel's depth
    #: is its row's ``z_fill`` (0 if inf), made where it is read
    #: (:meth:`filtered_depth`)
    z_fill: mi.Float | None = None

    @property
    def texel_row(self) -> mi.UInt32:
        """(n·d) row of every texel."""
        return _texel_rows(self.n, self.d)

    @property
    def n_filtered(self) -> int:
        return dr.width(self.rows)

    def filtered_depth(self, f, col) -> mi.Float:
        """The depth of texel ``col`` of filtered row ``f`` (an index into
        ``two_or_more(rows)``, as :meth:`gather_rows` numbers them)."""
        src = dr.gather(mi.UInt32, two_or_more(self.rows), f)
        texel = src * scalar_u32(self.d) + col
        z = dr.gather(mi.Float, self.z, texel)
        if self.z_fill is None:
            return z
        fill = dr.gather(mi.Float, self.z_fill, src)
        return dr.select(dr.gather(mi.Bool, self.series, texel), z,
                         dr.select(dr.isfinite(fill), fill, 0.0))

    def z_rows(self) -> mi.TensorXf:
        """(nf, d) depths of the filtered rows (as :meth:`gather_rows`
        numbers them), made from the map's evaluated arrays."""
        nf = dr.width(two_or_more(self.rows))
        f, col = Divisor(self.d).divmod(dr.arange(mi.UInt32, nf * self.d))
        return mi.TensorXf(self.filtered_depth(f, col), shape=(nf, self.d))

    def gather_rows(self, texel_values) -> mi.TensorXf:
        """(nf, d) tensor of a texel array restricted to the filtered rows
        (a single filtered row twice, nf = 2: :func:`~integrators.core.opaque.two_or_more`;
        ``frow`` names the first)."""
        d, d_o = self.d, Divisor(self.d)
        rows = two_or_more(self.rows)
        nf = dr.width(rows)
        row, col = d_o.divmod(dr.arange(mi.UInt32, nf * d))
        src = dr.gather(mi.UInt32, rows, row) * d_o.d + col
        return mi.TensorXf(dr.gather(mi.Float, texel_values, src), shape=(nf, d))


def _texel_rows(n: int, d: int) -> mi.UInt32:
    return Divisor(d).div(dr.arange(mi.UInt32, n * d))


def rectified_shadow_map(queries, rays, beta_b, depth_range: str = "slice",
                         rows_with=()) -> RectifiedShadowMap:
    """The rectified shadow map of the rows (module doc) from the blocker
    angles ``beta_b`` (n·d, one per light ray, π = unblocked) of
    :func:`~integrators.epipolar.blockers.trace_blocker_angles`;
    ``rows_with``: unevaluated arrays over the rows (n,) that a later
    stage reads, evaluated with the map's filtered rows (one kernel)."""
    if depth_range not in DEPTH_RANGES:
        raise ValueError(f"depth_range '{depth_range}' is not one of {list(DEPTH_RANGES)}.")
    n, d = queries.n, rays.d
    s = _texel_rows(n, d)
    lo, hi = query_beta_range(queries)
    lo_t, hi_t = dr.gather(mi.Float, lo, s), dr.gather(mi.Float, hi, s)
    in_view = beta_b < hi_t                     # shadows some query of the row
    if depth_range == "slice":
        def scale(rows):        # 0.5 / the row's span, where it is read (no kernel)
            return 0.5 / dr.maximum(dr.gather(mi.Float, hi, rows) - dr.gather(mi.Float, lo, rows),
                                    MIN_SPAN)
        series = in_view & (beta_b >= lo_t)
        lit = ~in_view
        z = (beta_b - lo_t) * scale(s)
        z_r = (queries.beta - dr.gather(mi.Float, lo, queries.row)) * scale(queries.row)
        z_r = dr.clip(z_r, 0.0, 0.5)
    else:
        blocked_row = _row_any(in_view, n, d)
        series = dr.gather(mi.Bool, blocked_row, s)
        lit = ~series
        z = dr.minimum(beta_b, math.pi) * (1.0 / math.pi)
        z_r = queries.beta * (1.0 / math.pi)
    # the rows' series counts and smallest series depths in one kernel with
    # the texels' classes and depths, then the rows filtered and their
    # numbers in one more; the filled depths (RectifiedShadowMap.z_fill) and
    # the queries' depths z_r are made where they are read
    count, z_min = _row_count(series, n, d), _row_min(series, z, n, d)
    dr.eval(count, z_min, z, series, lit)
    filtered = count > 0
    ones = dr.select(filtered, mi.UInt32(1), mi.UInt32(0))
    dr.schedule(ones, *rows_with)
    rows = dr.compress(filtered)
    frow = dr.prefix_sum(ones)   # exclusive
    smap = RectifiedShadowMap(n, d, z, series, lit, z_r, filtered, rows, frow, z_min)
    dr.eval(smap.filtered, smap.frow)
    return smap


def _row_count(mask, n: int, d: int) -> mi.UInt32:
    """Per row of ``d`` texels: how many are in ``mask`` (added by the
    kernel that makes the mask)."""
    count = dr.zeros(mi.UInt32, n)
    dr.scatter_reduce(dr.ReduceOp.Add, count, dr.select(mask, mi.UInt32(1), mi.UInt32(0)),
                      _texel_rows(n, d))
    return count


def _row_any(mask, n: int, d: int) -> mi.Bool:
    return _row_count(mask, n, d) > 0


def _row_min(series, z, n: int, d: int) -> mi.Float:
    """Per row: the smallest series depth (inf if none)."""
    z_min = dr.full(mi.Float, dr.inf, n)
    dr.scatter_reduce(dr.ReduceOp.Min, z_min, dr.select(series, z, dr.inf), _texel_rows(n, d))
    return z_min


# --------------------------------------------------------------------------
# Coverage sums Σ_g w_g clip(D − g, 0, 1)
# --------------------------------------------------------------------------

@dataclass(eq=False)
class Coverage:
    """Where each query's depth D cuts its row (module doc, "Coverage")."""
    d: int
    texel: mi.UInt32     # (Q,) flat index of texel k0 = min(⌊D⌋, d − 1)
    frac: mi.Float       # (Q,) covered part of texel k0, D − k0 ∈ [0, 1]
    j: mi.Float          # (Q,) D − 1: filtered_visibility's texel coordinate

    @staticmethod
    def of(queries, rays) -> "Coverage":
        d, d_o = rays.d, scalar_u32(rays.d)
        D, k0 = covered_depth(queries, rays, d_o)
        return Coverage(d, queries.row * d_o + k0, D - mi.Float(k0), D - 1.0)

    def sum(self, w) -> mi.Float:
        """Σ_g w_g clip(D − g, 0, 1) per query, ``w`` an (n·d) texel array."""
        return self.stacked_sums(w, 1)[0]

    def stacked_sums(self, stack, count: int) -> tuple:
        """:meth:`sum` of each of the ``count`` (n·d) texel arrays laid one
        after another in ``stack``, with one prefix sum over the stack (the
        rows' blocks are summed as :meth:`sum` sums them: each result is
        bit for bit its :meth:`sum`)."""
        size = dr.width(stack) // count
        P = dr.block_prefix_sum(stack, self.d, exclusive=True)
        return tuple(self.read(P, stack, None if k == 0 else opaque_scalar(mi.UInt32, k * size))
                     for k in range(count))

    def read(self, P, stack, offset=None, active=True) -> mi.Float:
        """Σ_g w_g clip(D − g, 0, 1) per query of the texel array laid at
        ``offset`` (lanes) in ``stack``, whose exclusive per-row prefix sums
        are ``P``: the prefix up to the query's last texel plus its covered
        fraction of that texel (0 where not ``active``)."""
        at = self.texel if offset is None else self.texel + offset
        return (dr.gather(mi.Float, P, at, active)
                + self.frac * dr.gather(mi.Float, stack, at, active))


# --------------------------------------------------------------------------
# The filter over the rows (§3.3)
# --------------------------------------------------------------------------

@dataclass(frozen=True)
class FilterSettings:
    """Options of :func:`~integrators.fourier.prefilter.prefix_filter` and
    :func:`~integrators.fourier.prefilter.filtered_visibility`."""
    M: int = 32
    regions: int = 1
    fit_depth: bool = False
    exact_bounds: bool = True


def texel_weight(w, texel) -> mi.Float:
    """Texel weights ``w`` at flat texels ``texel``: ``w`` an (n·d) array,
    a width-1 weight of every texel, or a function of the texel index
    (weights made from evaluated arrays where they are read, e.g. one
    layer of :func:`kernel_weights`: no texel array of their own)."""
    if callable(w):
        return w(texel)
    return w if dr.width(w) == 1 else dr.gather(mi.Float, w, texel)


def kernel_weights(L, K, size: int, first: int = 0, per: int = 0):
    """The texel weights ``L · K_l`` of layer ``l`` (``L`` (n·d), ``K`` the
    layers' kernels one after another from layer ``first``, ``size`` = n·d
    each; both evaluated) as a function ``w(l, texel)``, multiplied where
    it is read (no texel array of its own).  ``L`` a list of colour
    channels' factors over the same ``per`` kernels: layer ``c·per + k``
    weights by channel c's L and kernel k."""
    size_o, first_o = scalar_u32(size), opaque_scalar(mi.UInt32, first)
    if not isinstance(L, list) or len(L) == 1:
        L = L[0] if isinstance(L, list) else L
        return lambda l, texel: (dr.gather(mi.Float, L, texel)
                                 * dr.gather(mi.Float, K, (l + first_o) * size_o + texel))
    per_o = Divisor(per)

    def w(l, texel):
        c, k = per_o.divmod(l + first_o)
        L_t = dr.gather(mi.Float, L[-1], texel)
        for ch in reversed(range(len(L) - 1)):
            L_t = dr.select(c == ch, dr.gather(mi.Float, L[ch], texel), L_t)
        return L_t * dr.gather(mi.Float, K, k * size_o + texel)
    return w


def filter_depths(smap: RectifiedShadowMap, regions: int):
    """(z_rows, (z_lo, z_hi)): the filtered rows' depths
    (:meth:`RectifiedShadowMap.z_rows`) and their regions' depth bounds
    (:func:`~integrators.fourier.prefilter.region_depth_bounds`), made
    once per map: every filter of a frame (each weighting, each
    reference ray) reads the same."""
    def make():
        z = smap.z_rows()
        dr.schedule(z.array)        # with the bounds' inputs (one region: one kernel)
        bounds = region_depth_bounds(z, regions, smap.filtered_depth)
        dr.eval(z, *bounds)
        return z, bounds
    return frame_memo(smap, ("filter_depths", regions), make)


def prefilter_rows(smap: RectifiedShadowMap, w, opt: FilterSettings, layers: int = 1,
                   rows=None) -> FilteredBasis | None:
    """Filtered-basis textures of the filtered rows with texel weights ``w``
    (n·d, ≥ 0, or a function of the texel: :func:`texel_weight`; zeroed
    outside the series texels) (Listings 2-3), read in the filter's loop.
    ``layers`` > 1: that many filters of the rows stacked
    (:func:`~integrators.fourier.prefilter.prefix_filter`'s ``layers``),
    ``w(l, texel)`` the weights of layer ``l``; ``rows``: ``None`` or
    ``rows(l, row)``, whether layer ``l`` filters row ``row`` (< n; the
    others' textures stay 0: visibility 1 where read)."""
    if smap.n_filtered == 0:
        return None
    z, bounds = filter_depths(smap, opt.regions)
    d_o = scalar_u32(smap.d)
    src_rows = two_or_more(smap.rows)           # as gather_rows numbers them
    per = Divisor(dr.width(src_rows))

    def at(row):                                # (layer, source row) of a stacked row
        l, r = per.divmod(row) if layers > 1 else (0, row)
        return l, dr.gather(mi.UInt32, src_rows, r)

    def weights(row, i):
        l, src = at(row)
        texel = src * d_o + i
        value = w(l, texel) if layers > 1 else texel_weight(w, texel)
        return dr.select(dr.gather(mi.Bool, smap.series, texel), value, 0.0)

    active = None if rows is None else (lambda row: rows(*at(row)))
    return prefix_filter(z, weights, opt.M, opt.regions, opt.fit_depth, bounds=bounds,
                         rows=active, layers=layers)


def series_visibility(smap: RectifiedShadowMap, fb: FilteredBasis | None, queries,
                      cover: Coverage, opt: FilterSettings, clamp: bool, band: float = 0.0):
    """Weighted average visibility of each query over the series texels in
    front of its depth (Listing 4); 1 in rows without series texels.
    ``band`` > 0: ``(V, drop)``, also the drop of the average across the
    query's depth ± ``band`` (:func:`~integrators.fourier.prefilter.filtered_visibility`)."""
    if fb is None:
        ones = dr.full(mi.Float, 1.0, queries.count)
        return ones if band <= 0.0 else (ones, dr.zeros(mi.Float, queries.count))
    active = dr.gather(mi.Bool, smap.filtered, queries.row)
    frow = dr.gather(mi.UInt32, smap.frow, queries.row)
    frow = dr.select(active, frow, 0)
    return filtered_visibility(fb, frow, cover.j, smap.z_r, clamp, opt.exact_bounds, active,
                               band)


# --------------------------------------------------------------------------
# Where the series is no estimate: the step blurred over the query's own weight
# --------------------------------------------------------------------------

#: half-width of the band around a query's depth, in units of 1/M of the
#: [0, 1] depth range, in which the truncated series blurs the step: its
#: Gibbs peak lies 1/M from the step (:mod:`integrators.fourier.basis`)
NEAR_BAND = 2.0
#: the band's half-width at least, in depth units, whatever M: the
#: truncated series' ringing falls off only as 1/(M Δ) with the distance Δ
#: from the step, so past 2/M a receiver behind its blocker still reads
#: light that is not there (held-out seed 2010 at 640x480, a spot light
#: past box blockers: with the band 2/M, 32 coefficients relMSE 9.6e-5 and
#: 64 2.0e-5 where 16 had 2.0e-6 -- more coefficients, more leak; with this
#: floor 3.0e-6 at 32, at 1.01x the time; on 14 held-out point and spot
#: scenes at 320x240 no error grew)
NEAR_BAND_MIN = 0.125
#: a query whose series texels within the band weigh more than this
#: fraction of its shadowed sum ...
NEAR_TOLERANCE = 2.0
#: ... and more than this fraction of its unshadowed sum takes the exact sum
NEAR_FLOOR = 1e-4


def near_band(M: int) -> float:
    """The band half-width in depth units for ``M`` coefficients:
    :data:`NEAR_BAND` / M, at least :data:`NEAR_BAND_MIN`."""
    return max(NEAR_BAND / M, NEAR_BAND_MIN)


def near_step_weight(series, drop) -> mi.Float:
    """Σ w of the series texels in front of each query's depth whose depth
    lies within the band around the query's (about): their weight sum
    ``series`` (:func:`class_and_total_sums`) times the ``drop`` of the filtered
    average across the band."""
    return series * dr.maximum(drop, 0.0)


def series_unreliable(near, S, P) -> mi.Bool:
    """(Q,) queries whose filtered sum ``S`` is mostly the blurred step:
    the near-step weight ``near`` above ``NEAR_TOLERANCE`` of ``S`` and
    above ``NEAR_FLOOR`` of the unshadowed weight ``P``.  Receivers right
    behind their blockers -- fog in front of a surface seen from its
    shadowed side, a view ray grazing an occluder -- read up to half the
    weight of those texels as light that is not there (a point
    light inside a closed box, random stress seed 43, 1.3e-2 of the
    unoccluded peak where the exact answer is 0)."""
    return (near > NEAR_TOLERANCE * S) & (near > NEAR_FLOOR * P)


def series_sum(smap: RectifiedShadowMap, cover: Coverage, w, V_series) -> mi.Float:
    """Σ over the series texels of w_g V(g, β_q) clip(D − g, 0, 1): their
    weight sum times the filtered average ``V_series``."""
    return cover.sum(dr.select(smap.series, w, 0.0)) * V_series


def class_and_total_sums(smap: RectifiedShadowMap, cover: Coverage, w):
    """(Σ_lit, Σ_series, Σ_all) of w_g clip(D − g, 0, 1) per query: the
    covered weight of the lit texels, of the series texels and of all (the
    shadowed sum is ``Σ_lit + Σ_series · V̄_series``, :func:`shadowed_sum`),
    from one kernel and one prefix sum over the three masked copies of
    ``w``."""
    return cover.stacked_sums(_class_stack(smap, lambda k, g: texel_weight(w, g), 1), 3)


#: most texel weights of one prefix sum of :func:`stacked_class_sums`
#: (its memory: this many floats in and out)
STACK_LIMIT = 1 << 25


@dataclass(eq=False)
class ClassSums:
    """(Σ_lit, Σ_series, Σ_all) of :func:`class_and_total_sums` for each of
    ``count`` weightings, read per query from the prefix sums of their
    stacked masked copies (``batches``: (first weighting, count, prefix
    sums, stack) of each prefix sum)."""
    cover: Coverage
    size: int
    count: int
    batches: list

    def of(self, k: int) -> tuple:
        """The three sums of weighting ``k`` (every query)."""
        first, _, P, stack = next(b for b in self.batches if b[0] <= k < b[0] + b[1])
        return tuple(self.cover.read(P, stack, scalar_u32(3 * (k - first) + c)
                                     * scalar_u32(self.size)) for c in range(3))

    def at(self, k: mi.UInt32, active=True) -> tuple:
        """The three sums of weighting ``k[q]`` for each query q (0 where
        not ``active``), bit for bit :meth:`of`."""
        out = [mi.Float(0.0)] * 3
        for first, count, P, stack in self.batches:
            here = (mi.Bool(active) & (k >= opaque_scalar(mi.UInt32, first))
                    & (k < opaque_scalar(mi.UInt32, first + count)))
            j = k - opaque_scalar(mi.UInt32, first)
            out = [dr.select(here, self.cover.read(P, stack, (3 * j + c) * scalar_u32(self.size),
                                                   here), x) for c, x in enumerate(out)]
        return tuple(out)


def stacked_class_sums(smap: RectifiedShadowMap, cover: Coverage, L, K, count: int,
                       per: int = 0) -> ClassSums:
    """:func:`class_and_total_sums` of the weights ``L · K_k`` of each of
    ``count`` kernels laid one after another in ``K`` (``count``·n·d;
    :func:`kernel_weights`, ``L`` a list of channels over ``per`` kernels
    each: their ``count`` = channels · ``per`` layers), bit for bit, as few
    prefix sums as ``STACK_LIMIT`` allows (one for a frame's reference
    rays), their inputs in one kernel (batches of equal width, the last
    padded with zero weights)."""
    size = dr.width(smap.lit)
    per_batch = max(1, STACK_LIMIT // (3 * size))
    per_batch = -(-count // -(-count // per_batch))      # balanced: equal widths
    batches = []
    for first in range(0, count, per_batch):
        n = min(per_batch, count - first)
        batches.append((first, n, _class_stack(smap, kernel_weights(L, K, size, first, per),
                                               per_batch, n if count > per_batch else None)))
    dr.eval([b[2] for b in batches])
    return ClassSums(cover, size, count,
                     [(first, n, dr.block_prefix_sum(stack, cover.d, exclusive=True), stack)
                      for first, n, stack in batches])


def _class_stack(smap: RectifiedShadowMap, weight, count: int, used: int | None = None):
    """The 3·count masked copies (lit, series, all) of ``count`` weightings
    ``weight(k, g)`` (k < count, g a texel), one after another; ``used``:
    only the first ``used`` weightings (the others' copies 0)."""
    size = dr.width(smap.lit)
    j, g = Divisor(size).divmod(dr.arange(mi.UInt32, 3 * count * size))
    k, c = j // 3, j % 3
    keep = dr.select(c == 0, dr.gather(mi.Bool, smap.lit, g),
                     dr.select(c == 1, dr.gather(mi.Bool, smap.series, g), True))
    if used is None:
        return dr.select(keep, weight(k, g), 0.0)
    used_o = opaque_scalar(mi.UInt32, used)
    return dr.select(keep & (k < used_o), weight(dr.minimum(k, used_o - 1), g), 0.0)


def shadowed_sum(smap: RectifiedShadowMap, cover: Coverage, w, V_series) -> mi.Float:
    """Σ_g w_g V(g, β_q) clip(D − g, 0, 1) per query: the lit texels
    exactly, the series texels through the filter (:func:`series_sum`)."""
    return cover.sum(dr.select(smap.lit, w, 0.0)) + series_sum(smap, cover, w, V_series)


# -- texel integrals of the kernel (Eq. 12) --

def texel_integral(gamma_lo, width, c):
    """∫ e^{-c γ} dγ over the texel [γ_lo, γ_lo + width]:
    ``e^{-c γ_lo} · width · φ(c · width)`` (φ:
    :func:`~integrators.epipolar.query_terms.cell_average`, stable for c → 0).

    With c = σt (1 − cos β)/sin β = σt tan(β/2) (the joined camera- and
    light-side decay of a directional light per unit γ) this is, times
    σt/sin β, Klehm's Eq. 12 weight σt ∫_texel T dt =
    T(start)·(1 − T(across)) of the texel along the reference ray; here
    the texel edges come from the projective map itself (any spacing)
    instead of Eq. 12's geometric progression (:func:`eq12_weights_reference`)."""
    return dr.exp(-c * gamma_lo) * width * cell_average(c * width)


def texel_integral_reference(gamma_lo, width, c) -> np.ndarray:
    """NumPy oracle of :func:`texel_integral` (float64, the difference of
    the antiderivative)."""
    g0, w, c = (np.asarray(v, np.float64) for v in (gamma_lo, width, c))
    with np.errstate(divide="ignore", invalid="ignore"):
        exact = (np.exp(-c * g0) - np.exp(-c * (g0 + w))) / c
    return np.where(c * w < 1e-12, np.exp(-c * g0) * w, exact)


def eq12_weights_reference(delta: float, ratio: float, sigma_t: float, n: int) -> np.ndarray:
    """Klehm's Eq. 12 as printed: ``w'_i = e^{-Δσt Σ_{j=1}^{i-1} d^{j-1}}
    (1 − e^{-Δσt d^{i-1}})``, i = 1..n -- texel i spanning Δ·d^{i-1} along
    the ray (a geometric progression of ratio ``d``, estimated by Klehm
    from the first three texel centres).  The projective map's texels are
    a geometric progression only approximately (the map preserves the cross
    ratio, not the ratio of neighbouring lengths); :func:`texel_integral`
    uses the exact edges."""
    lengths = delta * float(ratio) ** np.arange(n)
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    return np.exp(-sigma_t * starts) * -np.expm1(-sigma_t * lengths)


def eq12_ratio_reference(t_centres) -> float:
    """Klehm's factor d from the first three texel centres along a ray:
    the ratio of the distances between them, (t_2 − t_1)/(t_1 − t_0)."""
    t = np.asarray(t_centres, np.float64)
    return float((t[2] - t[1]) / (t[1] - t[0]))
