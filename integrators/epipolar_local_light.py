"""Point and spot lights in the epipolar tree (Baran et al. 2010, §9).

The slices, the queries and the sweep are those of the directional light
(:mod:`integrators.epipolar_setup`); §9 changes the light rays: γ is the
*angle at the light* between the light ray and the direction light -> eye
(:mod:`rectify` conventions).  This module holds what that changes.

Geometry (§9)
-------------
``o`` the pinhole, ``p_l`` the light, ``L = |p_l − o|``, the axis from ``o``
toward ``p_l``.  In slice α, view ray β (angle at ``o`` from the axis) and
light ray γ (angle at ``p_l`` from the direction toward ``o``) meet at the
third corner ``x`` of the triangle (o, p_l, x), whose angle is π − β − γ; by
the law of sines

    t = L sin γ / sin(β+γ)   (from the eye),   r = L sin β / sin(β+γ)   (from the light).

Along view ray β, γ grows from 0 (at the eye) to π − β (at infinity).

Integrand in γ (the §4 change of variables)
-------------------------------------------
``dt/dγ = L sin β / sin²(β+γ)``, hence ``dt / r² = dγ / (L sin β)``: the
1/r² fall-off and the Jacobian cancel up to a per-view-ray factor.  The
angle at ``x`` between −ω and the direction to the light is θ = π − β − γ,
so ``cos θ = −cos(β+γ)`` and the phase function is a function of β+γ.  With
the light-side path ``τ = r − r_in(α, γ)`` (``r_in``: where the light ray
enters the medium box, 0 for a light inside it; ``x`` is always inside)

    L_scat = σs / (L sin β) ∫ I(α,γ) e^{-σt (L − r_in)} · K(γ, β) · V dγ,
    K(γ, β) = e^{-σt (t + r − L)} f_p(β+γ),
    t + r − L = 2L x / (1 − x),   x = tan(β/2) tan(γ/2)

(the half-angle form of ``L (sin β + sin γ − sin(β+γ)) / sin(β+γ)``: exact
and stable; x < 1 ⟺ β+γ < π).  ``I(α, γ)`` is Mitsuba's intensity with the
spot fall-off and projected texture: per light ray, initialised into the
tree like §6's textured light, together with ``e^{-σt (L − r_in)}``
(:func:`light_ray_factor`).  For L → ∞ with γ = γ_dir/L the kernel becomes
the directional ``e^{-σt γ_dir tan(β/2)}``.

Visibility
----------
On light ray γ, ``dr/dβ = L sin γ / sin²(β+γ) > 0``: the distance from the
light grows with β.  A light ray first blocked at ``r_b`` shades exactly
the view rays with ``β > β_b``, β_b = the eye's angle of the blocker point:
the directional rule, so the sweep over increasing β (Fig. 6) needs no
change (:func:`trace_local_blocker_angles`, traced from ``p_l``;
:func:`~integrators.epipolar_setup.shadow_map_blocker_angles` with
:func:`radial_map_point` and :func:`radial_blocker_beta`, read from the
perspective/cube shadow map).

Light rays (:func:`local_light_ray_grid`)
-----------------------------------------
Row α needs ``[γ_lo, γ_hi]``: ``[0, max γ_end]`` for a point light, clipped
to the spot cone's γ-interval in the slice for a spot light
(:func:`cone_interval`; rows outside the cone are dark: one light ray, no
updates, the sweep's closed form).  Uniform in γ = uniform in ``∫ dt/r²``
(equiangular sampling).  All rows share one lattice ``γ = j·Δγ`` (Δγ: the
widest row's range / (d − 1)); a row starts at a lattice point and has
``d_count ≤ d`` light rays, so the kernel's light-ray factors are computed
once per lattice cell, not once per (row, light ray).

Kernel separation (:func:`separate_local_channel`, :class:`LocalSeparation`)
----------------------------------------------------------------------------
K is sampled as in the directional case (log-spaced grids, γ-quadrature
weights, each view ray normalised), SVD'd and extended exactly (Nyström)
in Dr.Jit.  K only matters where queries use it (x ≤ x_max, the largest x
of a query's end point); beyond, the exponent is continued linearly in x
(C¹), which keeps K smooth and of low rank on the whole rectangle
(:func:`attenuation_exponent`).  Each leaf holds the mean of K over its
interval, integrated in the variable E (exact for a pure exponential --
K near the eye -- and for E bending within the interval, toward the
anti-epipole), with the phase at the interval's e^{-E}-weighted centroid
(:meth:`LocalKernel.cell_mean`).

Per query (:func:`local_query_terms`)
-------------------------------------
``σs·colour·Δγ / (L sin β)`` times the sweep's sum, re-based to the ray
origin (``e^{σt t_near}``), minus the part between pinhole and near plane
(one midpoint sample of the exact integrand, lit as the first leaf says).

Ring (§6): view rays within ``ring_degrees`` of the light or of its
opposite are ray-marched (:func:`~integrators.epipolar_setup.march_ring`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify.coords import direction_to_alpha_beta

from .epipolar_setup import (EpipolarQueries, EqualLightRays, MIN_AUTO_LIGHT_RAYS, QueryTerms,
                             gray, light_ray_channels, mode_visibility, factor_arrays,
                             light_ray_count, light_side_extinction, row_gamma_end, sub_ray_gamma)
from .integrand_svd import log1p_grid, separate_sampled_kernel, widen_empty
from .kernel_separation import SeparatedChannel
from .kernel_table import nystrom_sums, tabulated_terms
from .light_transport import (slabs, color, first_blocker, phase_eval, point, sample_light, scalar,
                              segment_box, segment_weight, vector)
from .opaque import Divisor, floats

#: widening of a spot cone's γ-interval [rad] (float32 fall-off at the edge)
CONE_MARGIN = 1e-4


# --------------------------------------------------------------------------
# Light rays (§9)
# --------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class LocalLightRays(EqualLightRays):
    """Light rays on one lattice of angles at the light (module doc): every
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
    #: :mod:`integrators.row_subset`); None: 0..n-1
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
    (:func:`~integrators.epipolar_setup.remarch_samples`), at the cost of
    a few pixels' ring steps.  The budget is decided on the whole frame
    (``queries.whole_frame``), so a partial render's rows march what the
    full render does."""
    none = dr.zeros(mi.UInt32, 0)
    if params.light.kind != "spot" or not queries.count:
        return none

    def reached(q):
        lo, _, lit = cone_interval(params, q.frame, q.alpha)
        reach = (dr.gather(mi.Bool, lit, q.row)
                 & (dr.gather(mi.Float, lo, q.row) < q.gamma_end))
        hit = dr.zeros(mi.Bool, q.n_samples)
        dr.scatter(hit, True, q.sample, reach)
        return dr.compress(hit)
    whole = queries.whole_frame
    frame_wide = reached(whole)
    budget = max(CONE_MARCH_MIN, CONE_MARCH_FRACTION * queries.n_samples)
    if dr.width(frame_wide) > budget:
        return none
    return frame_wide if whole is queries else reached(queries)


def light_ray_range(params, queries: EpipolarQueries):
    """(γ_lo, γ_hi, lit) per row: ``[0, max γ_end]`` of the row's queries,
    clipped to the spot cone (:func:`cone_interval`); ``lit`` False for rows
    outside the cone (their γ range is then ``[0, max γ_end]``)."""
    gamma_max = row_gamma_end(queries, 1e-6)
    lo, hi, lit = cone_interval(params, queries.frame, queries.alpha)
    hi = dr.minimum(hi, gamma_max)
    lit &= hi > lo
    return dr.select(lit, lo, 0.0), dr.select(lit, hi, gamma_max), lit


def light_ray_spacing(lo, hi, lit, d: int, auto: bool, gamma_max) -> float:
    """Δγ of the light-ray lattice: the widest *lit* row's range ``[lo, hi]``
    over ``d − 1`` (a dark row's range carries no light).  Automatic ``d``
    (:func:`~integrators.epipolar_setup.auto_light_rays`, about one light ray
    per pixel of the image diagonal) spans the image as the light sees it,
    the widest row's whole ``[0, max γ_end]`` (``gamma_max``), and a spot's
    cone then takes its share of them, but at least
    ``MIN_AUTO_LIGHT_RAYS`` across its widest lit row: a narrow cone is
    not left with a few light rays, nor a wide one with more than the
    image's resolution asks for."""
    width_lit = float(dr.max(dr.select(lit, hi - lo, 0.0) if dr.any(lit)[0] else hi - lo)[0])
    delta = width_lit / (d - 1)
    if auto:
        whole = float(dr.max(gamma_max)[0]) / (d - 1)
        delta = max(delta, min(whole, width_lit / (MIN_AUTO_LIGHT_RAYS - 1)))
    return delta


def local_light_ray_grid(params, queries: EpipolarQueries, d: int = 0,
                         t_end_max: float = 0.0) -> LocalLightRays:
    """Light rays on one lattice (:class:`LocalLightRays`): ``Δγ`` = the
    widest row's range (:func:`light_ray_range`) / (d − 1), so that every
    row's range, its start snapped down to the lattice, fits in ``d`` light
    rays (``d = 0``: :func:`~integrators.epipolar_setup.auto_light_rays` with
    the longest camera path ``t_end_max``; only lit rows count); dark rows
    get one light ray.
    Rows with a narrow range thus get fewer light rays, at the common
    spacing, and the kernel is evaluated once per lattice cell
    (:class:`LocalSeparation`)."""
    frame = queries.frame
    lo, hi, lit = light_ray_range(params, queries)
    auto = not d
    d = max(int(light_ray_count(params, d, t_end_max)), 2)
    delta = max(light_ray_spacing(lo, hi, lit, d, auto, row_gamma_end(queries, 1e-6)), 1e-7)
    delta = scalar(delta)
    m = mi.UInt32(dr.floor(lo / delta))
    start = mi.Float(m) * delta
    count = mi.UInt32(dr.clip(dr.ceil((hi - start) / delta), 1, scalar(d)))
    count = dr.select(lit, count, 1)
    rays = LocalLightRays(d, start + mi.Float(count) * delta, dr.zeros(mi.Float, queries.n) + delta,
                          start, offset=m, d_count=count)
    s, gamma = rays.positions(0.5)
    w = light_ray_direction(frame, dr.gather(mi.Float, queries.alpha, s), gamma)
    t_near, t_far = slabs(mi.Point3f(point(frame.light_position)), w,
                           point(params.medium.bounds_min), point(params.medium.bounds_max))
    rays = replace(rays, r_in=dr.select(t_far >= dr.maximum(t_near, 0.0),
                                        dr.maximum(t_near, 0.0), dr.inf))
    dr.eval(rays.gamma_max, rays.delta_gamma, rays.gamma_lo, rays.r_in, rays.offset, rays.d_count)
    return rays


def light_intensity(params, frame, w) -> mi.Color3f:
    """Mitsuba's intensity toward unit directions ``w`` from the light (spot
    fall-off and texture included): the delivered radiance at distance ``L``
    times ``L²``."""
    ell = float(frame.light_distance)
    _, _, spec = sample_light(params, point(frame.light_position) + w * scalar(ell))
    return spec * scalar(ell * ell)


def projects_texture(params) -> bool:
    """Whether the light is a spot light with a projected ``texture``."""
    return params.light.kind == "spot" and params.light.textured


def _channels(params) -> int:
    """Colour channels of the per-light-ray factor: 1 for an untextured light
    in a grey medium (its colour is then a per-query factor), else 3."""
    return 1 if (not projects_texture(params) and gray(params.medium.sigma_t)) else 3


def _light_colour(params, frame) -> mi.Color3f:
    """The intensity along the spot axis (fall-off 1), or of the point light."""
    axis = params.light.spot_axis if params.light.kind == "spot" else frame.axis
    return light_intensity(params, frame, vector(axis))


def light_ray_factor(params, queries: EpipolarQueries, rays: LocalLightRays, k: int = 1,
                     seed: int = 0):
    """(L, colour, lit): the tree's per-light-ray factor (§6 textured light)

        L(α, γ) = Ī(α, γ) · e^{-σt (L − r_in(α, γ))}

    (n, d) or (n, d, 3) (:func:`_channels`), Ī the intensity averaged over
    the ``k`` sub-rays of :func:`~integrators.epipolar_setup.sub_ray_gamma`
    (same ``seed``: the blockers' sub-rays; prefilters the texture and the
    cone's edge); ``colour``: the light's intensity along its axis when L
    is grey (L then holds the fall-off alone), else 1; ``lit`` (n·d·k,):
    existing sub-rays carrying light."""
    frame = queries.frame
    s, gamma = sub_ray_gamma(rays, k, seed)
    idx = dr.compress(rays.used(k))           # sub-rays of existing light rays
    w = light_ray_direction(frame, dr.gather(mi.Float, queries.alpha, dr.gather(mi.UInt32, s, idx)),
                            dr.gather(mi.Float, gamma, idx))
    I = light_intensity(params, frame, w)
    lit = dr.zeros(mi.Bool, dr.width(s))
    dr.scatter(lit, dr.max(I) > 0, idx)
    n_rays = queries.n * rays.d
    I_sum = dr.zeros(mi.Color3f, n_rays)
    dr.scatter_reduce(dr.ReduceOp.Add, I_sum, I, idx // k)
    I_mean = I_sum * (1.0 / k)
    sigma_t = np.asarray(params.medium.sigma_t, np.float64)
    depth = scalar(frame.light_distance) - rays.r_in
    if _channels(params) == 1:
        colour = _light_colour(params, frame)
        intensity = np.array([float(colour[i][0]) for i in range(3)])
        c = int(np.argmax(intensity))
        scale = 1.0 / intensity[c] if intensity[c] > 0 else 0.0
        values = [I_mean[c] * scalar(scale) * light_side_extinction(sigma_t[0], depth)]
    else:
        values = [I_mean[ch] * light_side_extinction(sigma_t[ch], depth) for ch in range(3)]
        colour = mi.Color3f(1.0)
    L = light_ray_channels(values, queries.n, rays.d)
    dr.eval(L.array, lit)
    return L, colour, lit


# --------------------------------------------------------------------------
# Blocker maps S[α, γ] (§3, §7, §9)
# --------------------------------------------------------------------------

def _eye_beta(frame, p) -> mi.Float:
    """β of world points ``p`` seen from the eye."""
    eye = point(frame.camera.origin)
    return direction_to_alpha_beta(frame, mi.Vector3f(p - eye))[1]


def trace_local_blocker_angles(params, queries: EpipolarQueries, rays: LocalLightRays,
                               k: int = 1, seed: int = 0, lit=None) -> mi.Float:
    """β_b = the eye's angle of the first blocker of ``k`` sub-rays per light
    ray, each traced with Mitsuba from ``p_l`` outward
    (:func:`~integrators.light_transport.first_blocker`: split at the medium
    box, which does not block); π where nothing blocks the sub-ray.  (n·d·k,)
    lanes in (row, light ray, sub-ray) order; only the ``lit`` sub-rays are
    traced (the others carry no light: π)."""
    frame = queries.frame
    s, gamma = sub_ray_gamma(rays, k, seed)
    idx = dr.arange(mi.UInt32, dr.width(s)) if lit is None else dr.compress(lit)
    out = dr.full(mi.Float, math.pi, dr.width(s))
    if dr.width(idx):
        alpha = dr.gather(mi.Float, queries.alpha, dr.gather(mi.UInt32, s, idx))
        w = light_ray_direction(frame, alpha, dr.gather(mi.Float, gamma, idx))
        origin = point(frame.light_position) + dr.zeros(mi.Vector3f, dr.width(idx))
        hit, p = first_blocker(params, origin, w)
        dr.scatter(out, dr.select(hit, _eye_beta(frame, p), math.pi), idx)
    dr.eval(out)
    return out


def radial_map_point(frame, alpha, gamma) -> mi.Point3f:
    """Point/spot light: the point of light ray (α, γ) at the eye's distance
    L from the light (where a perspective or cube map looks it up)."""
    p_l = point(frame.light_position)
    return p_l + light_ray_direction(frame, alpha, gamma) * scalar(frame.light_distance)


def radial_blocker_beta(params, frame, shadow_map, alpha, gamma, z_b) -> mi.Float:
    """Point/spot light: the eye's β of the blocker on light ray (α, γ) at
    ``r_b = z_b + bias`` from the light (a perspective or cube map's own
    test)."""
    p_l = mi.Point3f(point(frame.light_position))
    return _eye_beta(frame, p_l + light_ray_direction(frame, alpha, gamma) * (z_b + shadow_map.bias))


# --------------------------------------------------------------------------
# The kernel K(γ, β) and its separation (§6, Eq. 4)
# --------------------------------------------------------------------------

def attenuation_exponent(x, x_max: float, k: float, x_band=None):
    """(E, ∂E/∂x) of E(x) = k x / (1 − x) (k = 2σt L: E = σt (t + r − L)),
    continued linearly beyond ``x_max`` (module doc); with ``x_band`` (per
    lane, :func:`band_x`): held constant beyond ``min(x_band, x_max)``
    instead (the banded kernel, module doc); Dr.Jit or NumPy."""
    xm = x_max
    e_max, slope_max = k * xm / (1.0 - xm), k / (1.0 - xm) ** 2
    if isinstance(x, np.ndarray) or np.isscalar(x):
        if x_band is not None:
            xc = np.minimum(x, np.minimum(x_band, xm))
            return k * xc / (1.0 - xc), np.where(x <= xc, k / (1.0 - xc) ** 2, 0.0)
        xc = np.minimum(x, xm)
        inside = x <= xm
        return (np.where(inside, k * xc / (1.0 - xc), e_max + slope_max * (x - xm)),
                np.where(inside, k / (1.0 - xc) ** 2, slope_max))
    k, xm, e_max, slope_max = (scalar(v) for v in (k, xm, e_max, slope_max))
    if x_band is not None:
        xc = dr.minimum(x, dr.minimum(x_band, xm))
        return k * xc / (1.0 - xc), dr.select(x <= xc, k / dr.square(1.0 - xc), 0.0)
    xc = dr.minimum(x, xm)
    inside = x <= xm
    return (dr.select(inside, k * xc / (1.0 - xc), e_max + slope_max * (x - xm)),
            dr.select(inside, k / dr.square(1.0 - xc), slope_max))


def band_x(tan_half_beta, band_tan: float):
    """x = tan(β/2) tan(γ_b/2) at γ_b = π − β − w, the start of view ray
    β's asymptote band of width w (``band_tan`` = tan(w/2)): tan(γ_b/2) =
    cot((β + w)/2), so x_b = t (1 − t·band_tan) / (t + band_tan), t =
    tan(β/2); 0 where β + w ≥ π (the whole view ray is in the band);
    Dr.Jit or NumPy."""
    t = tan_half_beta
    if isinstance(t, np.ndarray) or np.isscalar(t):
        return np.maximum(t * (1.0 - t * band_tan) / np.maximum(t + band_tan, 1e-30), 0.0)
    band_tan = scalar(band_tan)
    return dr.maximum(t * (1.0 - t * band_tan) / dr.maximum(t + band_tan, 1e-30), 0.0)


def _phase(params, sin_b, cos_b, sin_g, cos_g) -> mi.Float:
    """f_p at view ray β, light ray γ: Mitsuba's phase function with
    ω = (sin β, 0, cos β) and wo = (−sin γ, 0, cos γ) (the slice plane, axis
    along z): ``wo·(−ω) = −cos(β+γ)`` (module doc)."""
    omega = mi.Vector3f(sin_b, 0.0, cos_b)
    wo = mi.Vector3f(-sin_g, 0.0, cos_g)
    # (an isotropic phase returns a literal: broadcast it to the lanes)
    width = max(dr.width(omega.x), dr.width(wo.x))
    return mi.Color3f(phase_eval(params, omega, wo)).x + dr.zeros(mi.Float, width)


def phase_of_angle(params, s) -> mi.Float:
    """f_p at the angle θ = π − s between −ω and the direction to the light
    (s = β + γ), evaluated by Mitsuba's phase function (Dr.Jit)."""
    sn, cs = dr.sincos(mi.Float(s))
    return _phase(params, sn, cs, 0.0, 1.0)


def phase_of_angle_numpy(params, s) -> np.ndarray:
    s = np.asarray(s, np.float64)
    return np.array(phase_of_angle(params, floats(s)),
                    np.float64).reshape(s.shape)


def _isotropic_value(params):
    """The constant f_p of an isotropic medium, else None."""
    if params.medium.phase_kind != "isotropic":
        return None
    return float(phase_of_angle(params, mi.Float(1.0))[0])


#: samples of the phase table used by the SVD's NumPy sample, over s ∈ [0, π]
PHASE_TABLE = 8193


def phase_table(params):
    """f_p(s) (s = β + γ ∈ [0, 2π]) as a callable for NumPy: exact for an
    isotropic phase, else linear interpolation in a table of PHASE_TABLE
    values from Mitsuba over [0, π] (f_p depends on cos s; relative error
    ~1e-7 for HG g = 0.5; the Nyström sums in Dr.Jit evaluate the phase
    function itself)."""
    iso = _isotropic_value(params)
    if iso is not None:
        return lambda s: iso
    n = PHASE_TABLE
    table = phase_of_angle_numpy(params, np.linspace(0.0, np.pi, n))
    table = np.append(table, table[-1])

    def f_p(s):
        u = (np.pi - np.abs(np.pi - np.asarray(s, np.float64))) * ((n - 1) / np.pi)
        i = np.clip(u.astype(np.int64), 0, n - 1)
        f = u - i
        return table[i] * (1.0 - f) + table[i + 1] * f
    return f_p


def local_kernel_numpy(params, sigma_t: float, L: float, x_max: float, f_p=None,
                       band_tan: float = 0.0):
    """K(γ, β) = e^{-E(x)} f_p(β+γ) in float64 (the SVD's sample);
    ``f_p``: a :func:`phase_table` (built here if None); ``band_tan`` > 0:
    the banded kernel (:func:`attenuation_exponent`, :func:`band_x`)."""
    k = 2.0 * sigma_t * L
    f_p = f_p or phase_table(params)

    def K(gamma, beta):
        gamma, beta = np.broadcast_arrays(np.asarray(gamma, np.float64),
                                          np.asarray(beta, np.float64))
        tb = np.tan(0.5 * beta)
        E, _ = attenuation_exponent(tb * np.tan(0.5 * gamma), x_max, k,
                                    band_x(tb, band_tan) if band_tan > 0 else None)
        return np.exp(-E) * f_p(beta + gamma)
    return K


@dataclass(eq=False)
class Angles:
    """``tan(a/2)``, ``sin a``, ``cos a`` of angles a (β or γ), computed once
    so that the Nyström loops need no trigonometry."""
    tan_half: mi.Float
    sin: mi.Float
    cos: mi.Float

    @staticmethod
    def of(a) -> "Angles":
        a = mi.Float(a)
        sn, cs = dr.sincos(a)
        return Angles(dr.tan(0.5 * a), sn, cs)

    @staticmethod
    def from_tan_half(t) -> "Angles":
        t = mi.Float(t)
        inv = dr.rcp(1.0 + t * t)
        return Angles(t, 2.0 * t * inv, (1.0 - t * t) * inv)

    def gather(self, k) -> "Angles":
        return Angles(*(dr.gather(mi.Float, v, k) for v in (self.tan_half, self.sin, self.cos)))


def _exponential_moments(u):
    """(φ1, φ2, μ) of e^{-u v} on v ∈ [0, 1]: φ1 = ∫e^{-uv} = (1 − e^{-u})/u,
    φ2 = ∫v e^{-uv} = (1 − (1+u) e^{-u})/u², and the centroid μ = φ2/φ1
    (1, ½, ½ at u = 0), sharing one exp."""
    small = u < 1e-2
    us = dr.select(small, 1.0, u)
    e = dr.exp(-us)
    phi1 = dr.select(small, 1.0 - u * (0.5 - u * (1.0 / 6.0)), (1.0 - e) / us)
    phi2 = dr.select(small, 0.5 - u * (1.0 / 3.0 - u * 0.125), (1.0 - (1.0 + us) * e) / (us * us))
    mu = dr.select(small, 0.5 - u * (1.0 / 12.0), dr.rcp(us) - e / (1.0 - e))
    return phi1, phi2, mu


@dataclass(eq=False)
class LocalKernel:
    """K(γ, β) = e^{-E(x)} f_p(β+γ) of one colour channel, in Dr.Jit
    (module doc); ``k = 2σt L``; ``band_tan`` > 0: the banded kernel,
    E held constant in view ray β's asymptote band (:func:`band_x`)."""
    params: object
    k: float
    x_max: float
    isotropic: float | None
    band_tan: float = 0.0

    @staticmethod
    def of(params, sigma_t: float, L: float, x_max: float,
           band_tan: float = 0.0) -> "LocalKernel":
        return LocalKernel(params, 2.0 * sigma_t * L, x_max, _isotropic_value(params), band_tan)

    def _x_band(self, b: "Angles"):
        return band_x(b.tan_half, self.band_tan) if self.band_tan > 0 else None

    def _phase(self, b: Angles, sin_g, cos_g):
        if self.isotropic is not None:
            return self.isotropic
        return _phase(self.params, b.sin, b.cos, sin_g, cos_g)

    def value(self, b: Angles, g: Angles) -> mi.Float:
        E, _ = attenuation_exponent(b.tan_half * g.tan_half, self.x_max, self.k,
                                    self._x_band(b))
        return dr.exp(-E) * self._phase(b, g.sin, g.cos)

    def _exponent(self, b: Angles, tg):
        """(E, ∂E/∂γ) at tan(γ/2) = tg."""
        E, dE = attenuation_exponent(b.tan_half * tg, self.x_max, self.k, self._x_band(b))
        return E, dE * b.tan_half * (0.5 * (1.0 + tg * tg))

    def _sub_mean(self, b: Angles, g: Angles, g_end: Angles, h):
        """Mean of K over one sub-interval ``[γ, γ_end]`` of width h, in the
        variable E with dγ/dE = 1/c linear in E between its ends,
        normalised so that it integrates to h:

            mean = e^{-E(γ)} [ρ₀ φ1(ΔE) + (ρ₁ − ρ₀) φ2(ΔE)] / ((ρ₀ + ρ₁)/2),

        ρ = ΔE/(c h) at each end (:func:`_exponential_moments`); the phase
        at the e^{-E}-weighted centroid (secant rate)."""
        E0, c0 = self._exponent(b, g.tan_half)
        E1, c1 = self._exponent(b, g_end.tan_half)
        a0, a1 = c0 * h, c1 * h
        dE = dr.maximum(E1 - E0, 0.0)
        phi1, phi2, mu = _exponential_moments(dE)
        flat = dr.maximum(a0, a1) < 1e-3            # E ≈ const: ΔE is mostly rounding
        rho0 = dE / dr.maximum(a0, 1e-30)
        rho1 = dE / dr.maximum(a1, 1e-30)
        bent = (rho0 * phi1 + (rho1 - rho0) * phi2) / dr.maximum(0.5 * (rho0 + rho1), 1e-30)
        value = dr.exp(-E0) * dr.select(flat, 1.0 - 0.25 * (a0 + a1), bent)
        if self.isotropic is not None:
            return value * self.isotropic
        s = dr.select(flat, 0.5, mu) * h             # ≤ h/2: sin, cos by their series
        s2 = s * s
        sin_s = s * (1.0 - s2 * (1.0 / 6.0) * (1.0 - s2 * (1.0 / 20.0)))
        cos_s = 1.0 - 0.5 * s2 * (1.0 - s2 * (1.0 / 12.0))
        return value * self._phase(b, g.sin * cos_s + g.cos * sin_s,
                                   g.cos * cos_s - g.sin * sin_s)

    def cell_mean(self, b: Angles, bounds: list, delta_gamma) -> mi.Float:
        """Mean of K over a light ray's interval of width Δγ, split at
        ``bounds`` (the angles of its CELL_SPLIT + 1 equally spaced points)
        into sub-intervals integrated by :meth:`_sub_mean`: exact for a pure
        exponential (K near the eye) and within ~0.3 % where E bends within
        the interval (toward the anti-epipole, thick media)."""
        h = delta_gamma * (1.0 / (len(bounds) - 1))
        total = 0.0
        for g, g_end in zip(bounds[:-1], bounds[1:]):
            total += self._sub_mean(b, g, g_end, h)
        return total * (1.0 / (len(bounds) - 1))


#: sub-intervals of a light ray's interval in :meth:`LocalKernel.cell_mean`
CELL_SPLIT = 8


def interval_bounds(gamma, delta_gamma) -> list:
    """Angles of the CELL_SPLIT + 1 points splitting ``[γ, γ + Δγ]``."""
    gamma = mi.Float(gamma)
    return [Angles.of(gamma + delta_gamma * (i / CELL_SPLIT)) for i in range(CELL_SPLIT + 1)]


def local_kernel(params, sigma_t: float, L: float, x_max: float, tan_half_beta, gamma,
                 delta_gamma=None) -> mi.Float:
    """K(γ, β) in Dr.Jit at ``tan(β/2)`` and γ; with ``delta_gamma``: its
    mean over ``[γ, γ + Δγ]`` (:meth:`LocalKernel.cell_mean`)."""
    kern = LocalKernel.of(params, sigma_t, L, x_max)
    b = Angles.from_tan_half(tan_half_beta)
    g = Angles.of(gamma)
    if delta_gamma is None:
        return kern.value(b, g)
    return kern.cell_mean(b, interval_bounds(gamma, delta_gamma), mi.Float(delta_gamma))


def local_ray_kernel(params, queries, rays: LocalLightRays, sigma_t: float):
    """The mean of K(γ, β) over light ray t's interval as a function of
    (flat light-ray index t, per-lane tan(β/2)) (:func:`local_kernel`); the
    point/spot light model's ``ray_kernel``."""
    s, gamma = rays.positions(0.0)
    L, x_max = float(queries.frame.light_distance), query_x_max(queries)
    delta = dr.gather(mi.Float, rays.delta_gamma, s)
    return lambda t, tan: local_kernel(params, sigma_t, L, x_max, tan, dr.gather(mi.Float, gamma, t),
                                       dr.gather(mi.Float, delta, t))


def separate_local_channel(params, sigma_t: float, L: float, x_max: float, gamma_lo: float,
                           gamma_hi: float, beta_lo: float, beta_hi: float, rank: int,
                           tol: float, band_tan: float = 0.0):
    """Separate K(γ, β) ≈ Σ_i a_i(γ) b_i(β) over [γ_lo, γ_hi] × [β_lo, β_hi]
    with :func:`~integrators.integrand_svd.separate_sampled_kernel`, as
    :func:`integrators.kernel_separation.separate_channel` does for the
    directional kernel; the light kinds differ in K, in the grids -- uniform
    in log(1 + c (γ − γ_lo)), c = σt L tan(β_hi/2) (K's steepest initial
    decay), and in log(1 + σt L Γ (tan(β/2) − tan(β_lo/2))) -- and in s_k,
    here the grid's quadrature of each view ray's ∫K dγ (no closed form).
    ``band_tan`` > 0: the banded kernel (:class:`LocalSeparation`).
    Returns ``(γ grid, tan(β grid / 2), WA, WB)``."""
    G = max(gamma_hi - gamma_lo, 1e-30)
    beta_lo, beta_hi = widen_empty(beta_lo, beta_hi)
    x_lo, x_hi = math.tan(0.5 * beta_lo), math.tan(0.5 * beta_hi)
    c = max(sigma_t * L * x_hi, 1e-6 / G)
    gamma_grid, weight = log1p_grid(c, gamma_lo, gamma_hi)
    w_gamma = weight(gamma_grid)
    cb = max(sigma_t * L * G, 1e-6)
    x_grid, _ = log1p_grid(cb, x_lo, x_hi)
    K = local_kernel_numpy(params, sigma_t, L, x_max, band_tan=band_tan)

    def scale(beta):
        b = np.asarray(beta, np.float64)
        integral = w_gamma @ K(gamma_grid[:, None], b.ravel()[None, :])
        return (1.0 / np.maximum(integral, 1e-300)).reshape(b.shape)

    return separate_sampled_kernel(K, gamma_grid, weight, x_grid, scale, (gamma_lo, gamma_hi),
                                   (beta_lo, beta_hi), rank, tol)


def query_x_max(queries: EpipolarQueries) -> float:
    """Largest x = tan(β/2) tan(γ_end/2) of the whole frame's queries' end
    points (< 1): a frame-wide choice, the same for a partial render's rows."""
    queries = queries.whole_frame
    x = dr.tan(0.5 * queries.beta) * dr.tan(0.5 * queries.gamma_end)
    return float(min(max(float(dr.max(x)[0]), 1e-6), 1.0 - 1e-6))


def lit_domain(params, queries: EpipolarQueries, rays: LocalLightRays):
    """(γ_lo, γ_hi, β_lo, β_hi): the rectangle on which the separated kernel
    must be accurate -- the light rays of the rows that carry light
    (:func:`light_ray_range`; all rows if none does) and the β of their
    queries, below π − γ_lo (a view ray at β reaches γ < π − β only).  A
    spot's dark rows start at γ = 0, where K is largest: a kernel separated
    to a relative tolerance over ``[0, γ_hi]`` is all error on a narrow cone
    far from the eye; and a view ray that meets no lit light ray has
    K ≈ 0 on the whole domain, which its normalisation would blow up."""
    lit = light_ray_range(params, queries)[2]
    if not dr.any(lit)[0]:
        lit = dr.full(mi.Bool, True, queries.n)
    gamma_lo = float(dr.min(dr.select(lit, rays.gamma_lo, dr.inf))[0])
    gamma_hi = float(dr.max(dr.select(lit, rays.gamma_max, -dr.inf))[0])
    seen = dr.gather(mi.Bool, lit, queries.row) & (queries.beta < scalar(math.pi - gamma_lo))
    if not dr.any(seen)[0]:
        seen = dr.full(mi.Bool, True, dr.width(queries.beta))
    beta_lo = float(dr.min(dr.select(seen, queries.beta, dr.inf))[0])
    beta_hi = float(dr.max(dr.select(seen, queries.beta, -dr.inf))[0])
    return gamma_lo, gamma_hi, beta_lo, beta_hi


@dataclass(frozen=True)
class LocalChannel(SeparatedChannel):
    """One colour channel of the §9 kernel, separated
    (:func:`separate_local_channel`), with its Dr.Jit terms
    (:func:`~integrators.kernel_table.nystrom_sums` of :class:`LocalKernel`)."""
    kernel: LocalKernel
    c_b: float              # the b-table's warp rate σt L (γ_hi − γ_lo)

    def a_terms(self, cells, count: int, lanes: int | None = None) -> list:
        """The mean of a_i over each lattice cell, ``cells = (bounds, Δγ)``
        (:func:`interval_bounds`)."""
        bounds, delta = cells
        b_grid = Angles.from_tan_half(floats(self.x_grid))
        return nystrom_sums(count, self.WA,
                            lambda k: self.kernel.cell_mean(b_grid.gather(k), bounds, delta))

    def b_terms(self, tan_half, lanes: int | None = None) -> list:
        """b_i at the queries' tan(β/2): it depends on β alone, so it is
        tabulated in tan(β/2) with the SVD grid's warp (``lanes``:
        :func:`~integrators.kernel_table.tabulated_terms`)."""
        g_grid = Angles.of(floats(self.gamma_grid))

        def b_sums(x):
            b = Angles.from_tan_half(x)
            return nystrom_sums(dr.width(x), self.WB, lambda k: self.kernel.value(b, g_grid.gather(k)))
        return tabulated_terms(tan_half, self.x_lo, self.x_hi, self.c_b, b_sums, lanes)


@dataclass(frozen=True)
class LocalSeparation:
    """The point/spot light's stages of
    :func:`integrators.kernel_separation.separate_kernel`: A is the mean of
    a_i over every cell of the light rays' lattice (:class:`LocalLightRays`),
    evaluated once per cell and gathered into the rows (leaf g of row s =
    cell m_s + g).

    ``band_cells`` > 0: the kernel separated is the *banded* one -- E held
    constant in the last ``band_cells`` lattice cells before each view
    ray's asymptote γ = π − β (:func:`band_x`) -- and the sweep's sum must
    be corrected there by :func:`asymptote_band_correction`.  With the
    light near the eye (L ≪ the view rays' lengths) every point farther
    than ~L/Δγ from the eye lies in those cells, so the whole rise of E
    (the camera-side transmittance) happens within ~1e-4 rad of the
    asymptote: a step along the diagonal β + γ = π that no rank-24 kernel
    resolves (random stress seeds 79, 233, 266: separation error 0.13 at rank
    24, per-query sums off by up to 5 %)."""
    band_cells: int = 0

    def band_tan(self, rays: LocalLightRays) -> float:
        """tan(w/2) of the band's width w = band_cells·Δγ (0: no band)."""
        if not self.band_cells:
            return 0.0
        return math.tan(0.5 * min(self.band_cells * float(rays.delta_gamma[0]), 3.0))

    def light_side_path(self, queries, rays: LocalLightRays):
        """L − r_in: the light side of each light ray (:func:`light_side_extinction`)."""
        return scalar(queries.frame.light_distance) - rays.r_in

    def channel(self, params, queries, rays: LocalLightRays, sigma_t: float, rank: int,
                tol: float) -> LocalChannel:
        L = float(queries.frame.light_distance)
        x_max = query_x_max(queries)
        band = self.band_tan(rays)
        gamma_lo, gamma_hi, beta_lo, beta_hi = lit_domain(params, queries, rays)
        sep = separate_local_channel(params, sigma_t, L, x_max, gamma_lo, gamma_hi,
                                     beta_lo, beta_hi, rank, tol, band_tan=band)
        return LocalChannel(math.tan(0.5 * beta_lo), math.tan(0.5 * beta_hi), *sep,
                            kernel=LocalKernel.of(params, sigma_t, L, x_max, band),
                            c_b=sigma_t * L * (gamma_hi - gamma_lo))

    def kernel_points(self, queries, rays: LocalLightRays):
        delta = dr.gather(mi.Float, rays.delta_gamma, mi.UInt32(0))
        M = rays.lattice_size
        return M, (interval_bounds(mi.Float(dr.arange(mi.UInt32, M)) * delta, delta), delta)

    def to_rows(self, A_cells, queries, rays: LocalLightRays, CN: int):
        """A[s, g, :] = A_cells[m_s + g, :]."""
        M = rays.lattice_size
        j = dr.arange(mi.UInt32, queries.n * rays.d * CN)
        per_ray, c = Divisor(CN).divmod(j)
        s_row, g = Divisor(rays.d).divmod(per_ray)
        cell = dr.minimum(dr.gather(mi.UInt32, rays.offset, s_row) + g, dr.opaque(mi.UInt32, M - 1))
        return dr.gather(mi.Float, A_cells, cell * dr.opaque(mi.UInt32, CN) + c)


# --------------------------------------------------------------------------
# Per-query terms
# --------------------------------------------------------------------------

#: Gauss-Legendre nodes and weights on [0, 1] of :func:`near_segment`
#: :func:`near_segment` takes its nodes where t_near exceeds this fraction of L
NEAR_RATIO = 0.05
NEAR_NODES = tuple((0.5 * (1.0 + x), 0.5 * w) for x, w in zip(*np.polynomial.legendre.leggauss(4)))


def near_segment(params, cap, queries: EpipolarQueries) -> mi.Color3f:
    """∫ over [0, t_near] (pinhole -> camera ray origin) of the unshadowed
    integrand σs f_p I/r² e^{-σt τ} e^{-σt t} dt, by Gauss-Legendre nodes
    in the angle θ the segment subtends at the light (equiangular, Kulla &
    Fajardo 2012: dt/r² = dθ/b, b the ray's distance from the light), so
    that 1/r² is integrated exactly: with the light a few near-plane
    distances from the eye, 1/r² changes by ~2× along the segment and one
    midpoint sample missed ~2 % of it (random stress seed 79: +0.5 % on the
    image).  Where t_near ≤ NEAR_RATIO·L (the suite), or the ray passes
    through the light (b ≈ 0), one midpoint sample."""
    sigma_t = color(params.medium.sigma_t)
    sigma_s = color(params.medium.sigma_s)
    omega = dr.gather(mi.Vector3f, cap.omega, queries.sample)
    o = mi.Point3f(point(params.camera.origin))
    q = mi.Vector3f(point(params.light.position)) - mi.Vector3f(o) \
        if params.light.position is not None else None
    t_near = queries.t_near

    def light_term(t):
        x = o + omega * t
        wo, dist, E = sample_light(params, x)
        tau, _, _ = segment_box(params, x, wo, dist)
        return sigma_s * phase_eval(params, omega, wo, x) * E * dr.exp(-sigma_t * tau), dist

    mid, _ = light_term(0.5 * t_near)
    value = mid * segment_weight(sigma_t, 0.0, t_near)
    # the nodes only where the segment is not short against the light's
    # distance (there the midpoint's error is below ~1e-4 of the segment)
    t0 = dr.dot(q, omega)
    b = dr.norm(q - omega * t0)
    idx = dr.compress((t_near > NEAR_RATIO * dr.norm(q)) & (b > 1e-4 * dr.norm(q)))
    if not dr.width(idx):
        return value
    omega = dr.gather(mi.Vector3f, omega, idx)
    t0, b, tn = dr.gather(mi.Float, t0, idx), dr.gather(mi.Float, b, idx), dr.gather(mi.Float, t_near, idx)
    th_a, th_b = dr.atan2(-t0, b), dr.atan2(tn - t0, b)
    total = dr.zeros(mi.Color3f, dr.width(idx))
    for u, w in NEAR_NODES:
        t = t0 + b * dr.tan(th_a + (th_b - th_a) * u)
        term, dist = light_term(t)
        total += term * dr.square(dist) * dr.exp(-sigma_t * t) * w
    dr.scatter(value, total * ((th_b - th_a) / b), idx)
    return value


def reaches_asymptote_band(queries: EpipolarQueries, rays: LocalLightRays,
                           band_cells: int) -> bool:
    """Whether any query's view ray reaches the asymptote band of
    ``band_cells`` lattice cells before its limit angle π − β (with a
    margin of one cell on each side: γ_end ≥ π − β − (band_cells + 2)·Δγ),
    i.e. whether the banded kernel and :func:`asymptote_band_correction`
    can change any query's sum.  Far from the light every view ray ends
    well before its limit angle, and the plain kernel is used."""
    if not band_cells or not queries.count:
        return False
    delta = dr.gather(mi.Float, rays.delta_gamma, mi.UInt32(0))
    near = queries.gamma_end >= (math.pi - queries.beta) - (band_cells + 2) * delta
    return bool(dr.any(near & (queries.beta < math.pi))[0])


def asymptote_band_correction(params, queries: EpipolarQueries, rays: LocalLightRays, A, B, L,
                               modes, last, band_cells: int) -> mi.Color3f:
    """Per query, the change of the sweep's sum when its light-ray cells in
    the asymptote band (:class:`LocalSeparation` with ``band_cells``: the
    lattice cells from ⌊(π − β)/Δγ⌋ − band_cells on) take the exact mean
    of K over their covered part instead of the banded kernel's Σ_i A_i B_i
    (added to ``terms.last``, integral units: Σ_g L_g V_g (K̄_g − K̃_g) cover_g).

    At most band_cells + 2 cells per query; only queries whose view ray
    reaches the band (farther than ~L sin β/(band_cells·Δγ) from the eye).
    Visibility: the cells' depth modes, the last cell's that of
    :func:`~integrators.epipolar_setup.last_interval_visibility` (``last``;
    :func:`~integrators.epipolar_setup.last_interval_correction` has already
    turned the sweep's V_leaf into it); ``modes`` None: every cell before
    the last is lit (``fourier_filter``'s unshadowed sum U); the exact mean
    is :meth:`LocalKernel.cell_mean` over the covered part."""
    out = dr.zeros(mi.Color3f, queries.count)
    if not band_cells or not queries.count:
        return out
    delta32 = np.float32(rays.delta_gamma[0])
    delta = scalar(delta32)
    m_s = mi.Float(dr.gather(mi.UInt32, rays.offset, queries.row))
    k0 = mi.Float(last.k0)
    # ÷Δγ as Dr.Jit compiles a division by a literal: × its float32 reciprocal
    j_a = dr.floor((math.pi - queries.beta) * scalar(np.float32(1.0) / delta32) - band_cells)
    g_a = dr.maximum(dr.maximum(j_a - m_s, k0 - (band_cells + 1)), 0.0)
    idx = dr.compress((g_a <= k0) & (queries.beta < math.pi))
    if not dr.width(idx):
        return out
    per = band_cells + 2
    lane = dr.arange(mi.UInt32, dr.width(idx) * per)
    owner, c = lane // per, lane % per
    q = dr.gather(mi.UInt32, idx, owner)
    g = dr.gather(mi.Float, g_a, q) + mi.Float(c)
    keep = dr.compress(g <= dr.gather(mi.Float, k0, q))
    q, g = dr.gather(mi.UInt32, q, keep), mi.UInt32(dr.gather(mi.Float, g, keep))
    row = dr.gather(mi.UInt32, queries.row, q)
    is_last = g == dr.gather(mi.UInt32, last.k0, q)
    cover = dr.select(is_last, dr.gather(mi.Float, last.f, q), 1.0)
    V_cells = (1.0 if modes is None else
               mode_visibility(modes, row, dr.gather(mi.UInt32, queries.col, q), g))
    V = dr.select(is_last, dr.gather(mi.Float, last.V, q), V_cells)
    beta = dr.gather(mi.Float, queries.beta, q)
    b = Angles.of(beta)
    gamma = rays.start(row) + mi.Float(g) * delta
    width = cover * delta
    bounds = interval_bounds(gamma, width)
    a, nA, d, CA, N = factor_arrays(A, True)
    bb, nB, _, CB, _ = factor_arrays(B, True)
    leaf = row * d + g
    slot = dr.gather(mi.UInt32, queries.slot, q)
    if L is not None:
        l, nL, _, CL, _ = factor_arrays(L, False)
    sigma_t = np.asarray(params.medium.sigma_t, np.float64)
    dist, x_max = float(queries.frame.light_distance), query_x_max(queries)
    kernels = [LocalKernel.of(params, float(sigma_t[ch]), dist, x_max) for ch in range(CA)]
    C = max(CA, CB, CL if L is not None else 1)
    exact = [cover * kern.cell_mean(b, bounds, width) for kern in kernels]
    per_channel = []
    for ch in range(C):
        sweep = mi.Float(0.0)
        for i in range(N):
            sweep += (dr.gather(mi.Float, a, (leaf * CA + ch % CA) * N + i)
                      * dr.gather(mi.Float, bb, (slot * CB + ch % CB) * N + i))
        v = V * (exact[ch % CA] - cover * sweep)
        if L is not None:
            v *= dr.gather(mi.Float, l, leaf * CL + ch % CL)
        acc = dr.zeros(mi.Float, queries.count)
        dr.scatter_reduce(dr.ReduceOp.Add, acc, v, q)
        per_channel.append(acc)
    return (mi.Color3f(per_channel[0], per_channel[0], per_channel[0]) if C == 1
            else mi.Color3f(*per_channel))


def local_query_terms(params, cap, queries: EpipolarQueries, rays: LocalLightRays, colour,
                      V_near=1.0) -> QueryTerms:
    """Per-query factors (module doc) for
    :func:`~integrators.epipolar_setup.assemble_queries`:
    ``radiance = e^{σt t_near}``, ``view = σs·colour·Δγ / (L sin β)``,
    ``near = V_near ·`` :func:`near_segment`."""
    sigma_t = color(params.medium.sigma_t)
    L = scalar(queries.frame.light_distance)
    dg = dr.gather(mi.Float, rays.delta_gamma, queries.row)
    view = color(params.medium.sigma_s) * colour * (dg / (L * dr.sin(queries.beta)))
    near = V_near * near_segment(params, cap, queries)
    return QueryTerms(dr.exp(sigma_t * queries.t_near), view, near)
