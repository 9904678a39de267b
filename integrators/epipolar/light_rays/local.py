"""Light rays of a point or spot light: rays from the light at angle γ in
each slice, spread over the lit cone of a spot light (Baran et al. 2010
§9; DESIGN §3).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from ...core.host_reads import row_extremes
from ...core.light_transport import medium_interval, point, scalar, vector
from ..queries import EpipolarQueries, frame_memo
from .directional import MIN_AUTO_LIGHT_RAYS, light_ray_count, row_gamma_end
from .layout import EqualLightRays, finite_or_inf, keep_lowest_light_side


#: widening of a spot cone's γ-interval [rad] (float32 fall-off at the edge)
CONE_MARGIN = 1e-4


# --------------------------------------------------------------------------
# Light rays (§9)
# --------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class LocalLightRays(EqualLightRays):
    """Light rays on one lattice of angles at the light (:mod:`integrators.epipolar`, "Light rays"): every
    row has the same ``Δγ``; row s starts at ``γ_lo = m_s·Δγ`` and has
    ``d_count[s] ≤ d`` light rays (leaf g of row s is lattice cell
    ``m_s + g``).  ``r_in`` (n·d,): distance from the light at which each
    light ray (centre) enters the medium box (0 inside it, +inf if it
    misses the box; set by :func:`local_light_ray_grid`)."""
    d: int
    gamma_max: mi.Float     # (n,) γ_lo + d_count·Δγ
    delta_gamma: mi.Float   # (n,) Δγ (the same for every row)
    gamma_lo: mi.Float      # (n,) m_s·Δγ
    offset: mi.UInt32       # (n,) m_s
    d_count: mi.UInt32      # (n,)
    r_in: mi.Float | None = None
    #: (n,) the rows' numbers in the whole frame (a partial render's rows,
    #: :mod:`integrators.partial.row_subset`); None: 0..n-1
    row_id: mi.UInt32 | None = None

    def row_counts(self) -> mi.UInt32:
        return self.d_count

    @property
    def lattice_size(self) -> int:
        """Lattice cells any row uses: max m_s + d."""
        return int(dr.max(self.offset)[0]) + self.d

    def used(self, per_ray: int = 1) -> mi.Bool:
        """(n·d·per_ray,) lanes of light rays that exist (g < d_count)."""
        s, g, _ = self.lanes(per_ray)
        return g < dr.gather(mi.UInt32, self.d_count, s)


def _basis(frame):
    return tuple(vector(v) for v in (frame.b1, frame.b2, frame.axis))


def light_ray_direction(frame, alpha, gamma) -> mi.Vector3f:
    """Unit direction from the light of light ray γ of slice α:
    ``sin γ (cos α b1 + sin α b2) − cos γ axis``."""
    b1, b2, ax = _basis(frame)
    sa, ca = dr.sincos(mi.Float(alpha))
    sg, cg = dr.sincos(mi.Float(gamma))
    return sg * (ca * b1 + sa * b2) - cg * ax


def cone_interval(params, frame, alpha):
    """(lo, hi, lit): the γ-interval of slice α inside a spot light's cone
    (``[0, π]`` and True for a point light).

    ``w(γ)·a = sin γ (perp·a) − cos γ (axis·a) = R cos(γ − φ)`` (a: the spot
    axis), so the cone ``w·a > cos(cutoff)`` is ``|γ − φ| < acos(cos(cutoff)/R)``,
    an arc of at most π (cutoff ≤ 90°) meeting ``[0, π]`` in one interval."""
    alpha = mi.Float(alpha)
    if params.light.kind != "spot":
        n = dr.width(alpha)
        return dr.zeros(mi.Float, n), dr.full(mi.Float, math.pi, n), dr.full(mi.Bool, True, n)
    a = np.asarray(params.light.spot_axis, np.float64)
    sa, ca = dr.sincos(alpha)
    p = ca * scalar(frame.b1 @ a) + sa * scalar(frame.b2 @ a)
    q = scalar(-float(frame.axis @ a))
    R = dr.sqrt(p * p + q * q)
    cos_c = scalar(math.cos(math.radians(params.light.cutoff_angle)))
    phi = dr.atan2(p, q)
    delta = dr.acos(dr.minimum(cos_c / dr.maximum(R, 1e-30), 1.0)) + CONE_MARGIN
    lo, hi = phi - delta, phi + delta
    wrapped = hi <= 0.0                      # the arc's copy shifted by 2π
    lo = dr.select(wrapped, lo + 2 * math.pi, lo)
    hi = dr.select(wrapped, hi + 2 * math.pi, hi)
    lo, hi = dr.maximum(lo, 0.0), dr.minimum(hi, math.pi)
    return lo, hi, (R > cos_c) & (hi > lo)


#: fewest automatic slices that must cross a spot light's cone
MIN_LIT_SLICES = 64
#: most slices one gap between two automatic slices is split into
MAX_LIT_SPLIT = 16


def resolve_lit_cone(params, frame, slices):
    """The automatic ``slices`` with more slices inside a spot light's
    cone where fewer than MIN_LIT_SLICES cross it (:func:`cone_interval`).

    A narrow spot lights few pixels, and their pixel centres' rays skim a
    beam a fraction of a pixel wide: a sample half a slice spacing from
    its slice then sees another part of the beam (the random stress set: the narrow
    spots: seeds 40, 117, 205 ... with 5 to 44 lit slices, mean -3 ... -5 %).
    Each gap between consecutive slices from the one before the first lit
    slice to the one after the last is split into ⌈MIN_LIT_SLICES / lit⌉
    (at most MAX_LIT_SPLIT) by lines through points evenly spaced between
    the two end points (:func:`rectify.slices.slices_from_points`)."""
    from rectify.slices import slices_from_points

    if params.light.kind != "spot" or slices.count < 2:
        return slices
    lit = np.array(cone_interval(params, frame, slices.alpha)[2], bool)
    count = int(lit.sum())
    if count == 0 or count >= MIN_LIT_SLICES:
        return slices
    split = min(MAX_LIT_SPLIT, math.ceil(MIN_LIT_SLICES / count))
    S = slices.count
    if slices.wraps:
        near = lit | np.roll(lit, 1) | np.roll(lit, -1)
    else:
        near = lit | np.r_[lit[1:], False] | np.r_[False, lit[:-1]]
    pts = [slices.points]
    f = (np.arange(1, split) / split)[:, None]
    for i in np.flatnonzero(near):
        j = i + 1
        if j == S:
            if not slices.wraps:
                continue
            j = 0
        if not near[j]:
            continue
        pts.append(slices.points[i] + f * (slices.points[j] - slices.points[i]))
    return slices_from_points(frame, np.concatenate(pts), method=slices.method)


#: a spot light lighting at most this fraction of the camera samples ...
CONE_MARCH_FRACTION = 1.0 / 64
#: ... or at most this many has them all ray-marched (:func:`cone_samples`)
CONE_MARCH_MIN = 256


def cone_samples(params, queries: EpipolarQueries) -> mi.UInt32:
    """The camera samples a narrow spot light's cone reaches -- a query of
    theirs lies in a slice inside the cone (:func:`cone_interval`) and its
    view ray reaches the cone's γ-interval -- when there are few of them
    (at most CONE_MARCH_FRACTION of the samples, or CONE_MARCH_MIN); else
    none.  Their pixel centres' rays skim a beam a fraction of a pixel
    wide, which the slices (even :func:`resolve_lit_cone`'s) resolve only
    to a few percent of its energy (random stress seeds 128, 216, 227: mean
    −3 … +11 %); the tree marches them like the ring
    (:func:`~integrators.epipolar.ring.remarch_samples`), at the cost of
    a few pixels' ring steps.  The budget is decided on the whole frame
    (``queries.whole_frame``), so a partial render's rows march what the
    full render does.

    Returns a function that lists them: the samples' test is queued here
    (a scatter over the queries) and runs with the next kernel over the
    queries -- a caller with one to launch calls this first."""
    none = dr.zeros(mi.UInt32, 0)
    if params.light.kind != "spot" or not queries.count:
        return lambda: none

    def reached(q):
        # the cone's interval of each query's row, at the query's lane (the
        # same arithmetic as over the rows: no kernel of its own)
        lo, _, lit = cone_interval(params, q.frame, dr.gather(mi.Float, q.alpha, q.row))
        reach = lit & (lo < q.gamma_end)
        hit = dr.zeros(mi.Bool, q.n_samples)
        dr.scatter(hit, True, q.sample, reach)
        return hit
    whole = queries.whole_frame
    frame_wide = reached(whole)
    own = frame_wide if whole is queries else reached(queries)

    def listed():
        budget = max(CONE_MARCH_MIN, CONE_MARCH_FRACTION * queries.n_samples)
        if dr.width(dr.compress(frame_wide)) > budget:
            return none
        return dr.compress(own)
    return listed


def light_ray_range(params, queries: EpipolarQueries):
    """(γ_lo, γ_hi, lit) per row: ``[0, max γ_end]`` of the row's queries,
    clipped to the spot cone (:func:`cone_interval`); ``lit`` False for rows
    outside the cone (their γ range is then ``[0, max γ_end]``)."""
    return _ranges(params, queries)[:3]


def _ranges(params, queries: EpipolarQueries):
    """:func:`light_ray_range` and the rows' ``[0, max γ_end]`` bound, made
    once per frame's queries (the lattice and the kernel's domain read
    them)."""
    def make():
        gamma_max = row_gamma_end(queries, 1e-6)
        lo, hi, lit = cone_interval(params, queries.frame, queries.alpha)
        hi = dr.minimum(hi, gamma_max)
        lit &= hi > lo
        out = dr.select(lit, lo, 0.0), dr.select(lit, hi, gamma_max), lit, gamma_max
        dr.eval(out)
        return out
    return frame_memo(queries, ("light_ray_range", params), make)


def light_ray_spacing(lo, hi, lit, d: int, auto: bool, gamma_max) -> float:
    """Δγ of the light-ray lattice: the widest *lit* row's range ``[lo, hi]``
    over ``d − 1`` (a dark row's range carries no light).  Automatic ``d``
    (:func:`~integrators.epipolar.light_rays.directional.auto_light_rays`, about one light ray
    per pixel of the image diagonal) spans the image as the light sees it,
    the widest row's whole ``[0, max γ_end]`` (``gamma_max``), and a spot's
    cone then takes its share of them, but at least
    ``MIN_AUTO_LIGHT_RAYS`` across its widest lit row: a narrow cone is
    not left with a few light rays, nor a wide one with more than the
    image's resolution asks for."""
    # the rows' evaluated arrays, copied (no kernel); float32 as on the device
    span = np.asarray(hi) - np.asarray(lo)
    lit_h = np.asarray(lit, bool)
    any_lit = bool(lit_h.any())
    widest_lit = max(row_extremes(span, lit_h)[1], 0.0)
    widest, longest = row_extremes(span)[1], row_extremes(gamma_max)[1]
    width_lit = widest_lit if any_lit else widest
    delta = width_lit / (d - 1)
    if auto:
        whole = longest / (d - 1)
        delta = max(delta, min(whole, width_lit / (MIN_AUTO_LIGHT_RAYS - 1)))
    return delta


def local_light_ray_grid(params, queries: EpipolarQueries, d: int = 0,
                         t_end_max: float = 0.0) -> LocalLightRays:
    """Light rays on one lattice (:class:`LocalLightRays`): ``Δγ`` = the
    widest row's range (:func:`light_ray_range`) / (d − 1), so that every
    row's range, its start snapped down to the lattice, fits in ``d`` light
    rays (``d = 0``: :func:`~integrators.epipolar.light_rays.directional.auto_light_rays` with
    the longest camera path ``t_end_max``; only lit rows count); dark rows
    get one light ray.
    Rows with a narrow range thus get fewer light rays, at the common
    spacing, and the kernel is evaluated once per lattice cell
    (:class:`~integrators.epipolar.kernel.local.LocalSeparation`)."""
    frame = queries.frame
    lo, hi, lit, gamma_max = _ranges(params, queries)
    auto = not d
    d = max(int(light_ray_count(params, d, t_end_max)), 2)
    delta = max(light_ray_spacing(lo, hi, lit, d, auto, gamma_max), 1e-7)
    delta = scalar(delta)
    m = mi.UInt32(dr.floor(lo / delta))
    start = mi.Float(m) * delta
    count = mi.UInt32(dr.clip(dr.ceil((hi - start) / delta), 1, scalar(d)))
    count = dr.select(lit, count, 1)
    rays = LocalLightRays(d, start + mi.Float(count) * delta, dr.zeros(mi.Float, queries.n) + delta,
                          start, offset=m, d_count=count)
    dr.eval(rays.gamma_max, rays.delta_gamma, rays.gamma_lo, rays.offset, rays.d_count)
    s, gamma = rays.positions(0.5)
    w = light_ray_direction(frame, dr.gather(mi.Float, queries.alpha, s), gamma)
    t_near, t_far = medium_interval(params, mi.Point3f(point(frame.light_position)), w)
    rays = replace(rays, r_in=dr.select(t_far >= dr.maximum(t_near, 0.0),
                                        dr.maximum(t_near, 0.0), dr.inf))
    # with r_in, the smallest finite light-side path L − r_in, kept for the
    # frame (what epipolar.light_factor.lowest_light_side reads)
    finite = finite_or_inf(scalar(frame.light_distance) - rays.r_in)
    dr.eval(rays.r_in, finite)
    lowest = float(dr.min(finite)[0]) if dr.width(finite) else math.inf
    keep_lowest_light_side(queries, rays, lowest)
    return rays
