"""Brute-force ray marching of the single-scattering integral (DESIGN §1):
the ``raymarch`` plugin's kernel, shared with the epipolar methods' ring
(Baran §6) and their last-interval checks.

Each camera ray ``x(t) = o + t·ω``, ``t ∈ [0, d]`` is cut into ``steps``
segments (:func:`step_boundaries`); on segment ``k`` the light term is
evaluated at one point and multiplied by the exact integral of the
camera-side transmittance over the segment (:func:`march`).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import drjit as dr
import mitsuba as mi

from .capture import sample_rng, seed_offset
from .light_transport import (color, light_transmittance, phase_eval, point, sample_light, scalar,
                              segment_box, segment_weight, vector, visible_confirmed, visible_exact)
from .opaque import opaque_scalar, reciprocal


def auto_spacing(params) -> str:
    """Equiangular segments for point/spot lights, uniform for directional."""
    return "uniform" if params.light.kind == "directional" else "equiangular"


def lit_spacing(params) -> str:
    """:func:`auto_spacing`, but ``cone`` for a spot light: the epipolar
    methods' marcher (ring, re-marched samples) puts its few steps where
    the light is."""
    return "cone" if params.light.kind == "spot" else auto_spacing(params)


#: the spot cone of ``cone`` spacing, widened by this angle [rad]
CONE_STEP_MARGIN = 1e-4


def step_boundaries(params, cap, steps, spacing):
    """t(s) for s in [0, steps]: where segment k = [t(k), t(k+1)] lies on each
    camera ray.  ``uniform``: t = d·s/steps.  ``equiangular`` (point/spot
    lights; Kulla & Fajardo 2012): uniform in the angle θ subtended at the
    light, t = t0 + b·tan θ (t0: the ray's closest approach to the light, b:
    its distance), so segments shrink where 1/r² peaks.  ``cone`` (spot
    lights): equiangular over the part of the ray inside the spot's cone
    alone (the light is zero elsewhere): a ray crossing a 1° beam gets all
    its steps in the beam instead of ~1/180 of them."""
    return _steps(params, cap, steps, spacing)[0]


def step_count(steps):
    """(loop bound, 1/steps) of a march of ``steps`` segments: an int (the
    same for every ray) or an ``mi.UInt32`` per ray; both opaque, and
    ``x·(1/steps)`` is bit for bit the ``x/steps`` of a kernel with the
    literal (the correctly rounded float32 reciprocal either way), so
    marches of any steps share their kernels."""
    if isinstance(steps, mi.UInt32):
        return steps, 1.0 / mi.Float(steps)
    return opaque_scalar(mi.UInt32, steps), reciprocal(steps)


def _steps(params, cap, steps, spacing):
    """(t(s), inverse-square correction c(s)) of :func:`step_boundaries`.
    ``c(s, offset)`` turns segment s's ``Δt / r²`` at the point the light
    is evaluated (``s + offset``) into the exact ``∫ dt / r² = Δθ / b``
    (:func:`inverse_square_factor`; 1 for uniform segments): at the ends of
    a ray that passes close to the light, where θ → ±π/2, one value of 1/r²
    is far from the segment's mean.  The boundaries are
    :func:`_bisection_steps`' angles swept from the ray's start, which stay
    exact on a ray nearly parallel to the direction to the light (the
    light behind the camera, at the anti-epipole)."""
    t_of = _bisection_steps(params, cap, steps, spacing)
    if spacing == "uniform" or params.light.position is None:
        return t_of, lambda s, offset: 1.0
    approach = closest_approach(params, cap)
    q, _, b = approach
    ok = b > 1e-6 * dr.norm(q)          # the ray is resolvably off the light

    def correction(s, offset):
        factor = inverse_square_factor(approach, t_of(s), t_of(s + 1), t_of(s + offset))
        return dr.select(ok, factor, 1.0)
    return t_of, correction


def closest_approach(params, cap):
    """(q, t0, b) per camera ray of a point/spot light: q = light − o, the
    ray parameter t0 of its closest point to the light and that distance b
    (r² = b² + (t − t0)² along the ray)."""
    q = mi.Vector3f(point(params.light.position) - cap.o)
    t0 = dr.dot(q, cap.omega)
    return q, t0, dr.norm(q - cap.omega * t0)


def _cone_angles(params, omega, q, t0, b, th_a, th_b):
    """[θ_a, θ_b] clipped to the spot cone.  The light sees the point at θ
    along ``w(θ) = cos θ n + sin θ ω`` (n: unit vector from the light to the
    ray's closest point), so ``w·a ≥ cos(cutoff)`` is ``R cos(θ − φ) ≥
    cos(cutoff)``, R = |(n·a, ω·a)|, φ = atan2(ω·a, n·a): one arc of at
    most π, which meets (−π/2, π/2) without wrapping.  A ray that misses
    the cone gets empty segments (θ_a = θ_b)."""
    a = vector(params.light.spot_axis)
    n = (omega * t0 - q) / b
    p, w = dr.dot(n, a), dr.dot(omega, a)
    R = dr.sqrt(p * p + w * w)
    cos_c = scalar(math.cos(math.radians(params.light.cutoff_angle)))
    phi = dr.atan2(w, p)
    delta = dr.acos(dr.minimum(cos_c / dr.maximum(R, 1e-30), 1.0)) + CONE_STEP_MARGIN
    lo = dr.clip(phi - delta, th_a, th_b)
    hi = dr.clip(phi + delta, th_a, th_b)
    hit = (R > cos_c) & (hi > lo)
    return dr.select(hit, lo, th_a), dr.select(hit, hi, th_a)


class PointTerms(NamedTuple):
    """The light term at points x = o + t·ω of the camera rays."""
    x: mi.Point3f
    wo: mi.Vector3f         # toward the light
    dist: mi.Float          # to the light (inf: directional)
    t_in: mi.Float          # the part [t_in, t_out] of x -> light inside the medium box
    t_out: mi.Float
    L_light: mi.Color3f     # Mitsuba's delivered radiance
    radiance: mi.Color3f    # σs · f_p · L_light · e^{-σt τ}: all but V and the segment weight

    def visible(self, params, active=True):
        """Ray-traced V(x) (:func:`~integrators.core.light_transport.visible_exact`)."""
        return visible_exact(params, self.x, self.wo, self.dist, self.t_in, self.t_out, active)


def point_terms(params, cap, t, active=True) -> PointTerms:
    """:class:`PointTerms` at ``t`` on each camera ray of ``cap``."""
    x = cap.o + cap.omega * t
    wo, dist, L_light = sample_light(params, x, active)
    tau, t_in, t_out = segment_box(params, x, wo, dist)
    f_p = phase_eval(params, cap.omega, wo, x)
    radiance = color(params.medium.sigma_s) * f_p * L_light * light_transmittance(params, tau)
    return PointTerms(x, wo, dist, t_in, t_out, L_light, radiance)


def march(params, cap, steps, shadow_map=None, jitter=False, seed=0, spacing="uniform",
          shadow_range=None):
    """L_scat per camera sample by ``steps`` analytic segments (see module doc).
    ``shadow_range = (t_lo, t_hi)`` per sample (Wyman & Ramsey 2008): exact
    visibility is traced only at points with ``t`` in it, ``V = 1`` elsewhere
    (:func:`integrators.core.hybrid_march.shadow_range`)."""
    n = dr.width(cap.d)
    sigma_t = color(params.medium.sigma_t)
    t_of, correction = _steps(params, cap, steps, spacing)
    if jitter:
        offset = sample_rng(cap.sample_index(),
                            seed_offset(seed, 0x853C49E6748FEA9B)).next_float32()
    else:
        offset = mi.Float(0.5)
    n_steps, _ = step_count(steps)

    def body(k, L):
        s = mi.Float(k)
        t = t_of(s + offset)
        pt = point_terms(params, cap, t)
        if shadow_map is None:
            active = True if shadow_range is None else \
                (t >= shadow_range[0]) & (t <= shadow_range[1])
            V = dr.select(pt.visible(params, active), 1.0, 0.0)
        else:
            V = shadow_map.visibility(pt.x)
        w = segment_weight(sigma_t, t_of(s), t_of(s + 1)) * correction(s, offset)
        L += pt.radiance * V * w
        return k + 1, L

    k, L = dr.while_loop(
        state=(mi.UInt32(0), dr.zeros(mi.Color3f, n)),
        cond=lambda k, L: k < n_steps,
        body=body,
    )
    return L


def inverse_square_factor(approach, lo, hi, t_mid):
    """∫_lo^hi dt / r² divided by (hi − lo) / r²(t_mid) on each camera ray
    (r: distance to the point/spot light; ``approach``: its
    :func:`closest_approach`, None for a directional light, factor 1): the
    factor that turns a light term evaluated at ``t_mid`` into the exact
    integral of its 1/r² over ``[lo, hi]`` (∫ dt / (b² + (t − t0)²) =
    Δθ / b, as :func:`step_boundaries`' equiangular segments).

    Δθ, the angle ``[lo, hi]`` subtends at the light, is one ``atan2`` of
    the tangent-difference formula, ``atan2(b·(hi − lo), b² + (hi − t0)(lo
    − t0))``, not the difference of two angles: for a ray nearly parallel
    to the direction to the light (the light straight behind the camera,
    b ≪ |t − t0|) both angles lie within float32's spacing (1.2e-7) of
    π/2, and their difference was 0 (a black pixel at the anti-epipole) or
    a few of those spacings over a much smaller Δθ.  Below Δθ = 1e-3 the
    ratio Δθ / (b·(hi − lo)) is its series ``(1 − x²/3) / den``, finite
    at b = 0 (∫ dt / (t − t0)²)."""
    if approach is None:
        return 1.0
    _, t0, b = approach
    span = hi - lo
    y = b * span
    den = dr.square(b) + (hi - t0) * (lo - t0)
    small = (den > 0.0) & (y <= 1e-3 * den)
    x = y / dr.select(small, den, 1.0)
    # ratio = ∫_lo^hi dt / r² / (hi − lo)
    ratio = dr.select(small, (1.0 - x * x * (1.0 / 3.0)) / dr.select(small, den, 1.0),
                      dr.atan2(y, den) / dr.select(small | (y <= 0.0), 1.0, y))
    r2 = dr.square(b) + dr.square(t_mid - t0)
    ok = (span > 1e-6 * dr.sqrt(r2)) & (small | (y > 0.0))
    return dr.select(ok, ratio * r2, 1.0)


def _bisection_steps(params, cap, steps, spacing):
    """t(s) of :func:`step_boundaries` for :func:`march_bisected`, with
    the angles measured from the ray's start: segment s ends where the
    ray has swept ``φ = φ_lo + (φ_hi − φ_lo)·s/steps`` at the light,
    ``t(φ) = |q|² sin φ / (b cos φ + t0 sin φ)`` (q, t0, b:
    :func:`closest_approach`), and the whole ray subtends ``Θ =
    atan2(b·d, |q|² − d·t0)``.  The absolute angles of :func:`_steps`
    (θ = atan2(t − t0, b), t = t0 + b·tan θ) lie within float32's spacing
    of ±π/2 on a ray nearly parallel to the direction to the light (the
    light behind the camera, near the anti-epipole): their first and last
    boundaries then missed 0 and d, or a θ rounded past π/2 sent the last
    ones back to 0.  Here t(0) = 0 and t(Θ) = d exactly.  ``cone``
    spacing (spot light): :func:`_cone_angles`' arc relative to the
    ray's start (its margin, 1e-4, far above their rounding)."""
    d = cap.d
    _, inv_steps = step_count(steps)
    uniform = lambda s: d * (s * inv_steps)        # noqa: E731
    if spacing == "uniform" or params.light.position is None:
        return uniform
    q, t0, b = closest_approach(params, cap)
    q2 = dr.squared_norm(q)
    ok = b > 1e-6 * dr.sqrt(q2)          # the ray is resolvably off the light
    b = dr.select(ok, b, 1.0)
    whole = dr.atan2(b * d, q2 - d * t0)
    lo, hi = dr.zeros(mi.Float, dr.width(d)), whole
    if spacing == "cone" and params.light.kind == "spot":
        th_a, th_b = dr.atan2(-t0, b), dr.atan2(d - t0, b)
        c_lo, c_hi = _cone_angles(params, cap.omega, q, t0, b, th_a, th_b)
        lo = dr.select(c_lo <= th_a, 0.0, dr.clip(c_lo - th_a, 0.0, whole))
        hi = dr.select(c_hi >= th_b, whole, dr.clip(c_hi - th_a, 0.0, whole))
        hi = dr.maximum(hi, lo)

    def t_of(s):
        phi = lo + (hi - lo) * (s * inv_steps)
        sin_phi, cos_phi = dr.sincos(phi)
        den = b * cos_phi + t0 * sin_phi          # > 0 on the ray (φ ≤ Θ < π)
        t = q2 * sin_phi / dr.select(den > 0.0, den, 1.0)
        t = dr.select((phi >= whole) | (den <= 0.0), d, t)
        return dr.select(ok, dr.clip(t, 0.0, d), uniform(s))
    return t_of


#: :func:`march_bisected` tests the lit state at the ray's end this fraction
#: of a segment before it (1e-4 still leaked on random seeds 43 and 98)
END_NUDGE = 1e-2


def march_bisected(params, cap, steps, bisections=12, spacing="uniform"):
    """L_scat per camera sample like :func:`march` with exact visibility,
    but each segment's lit part is located instead of sampled at one point:
    the lit test ℓ(x) = V(x) ∧ L_light(x) > 0 (ray-traced visibility, the
    spot's cone) is taken at both ends and the midpoint of each segment, and
    where it changes inside a half, ``bisections`` bisections find the
    crossing.  Each half's lit interval [a, b] then contributes its light
    term at its own midpoint times the exact ∫_a^b e^{-σt t} dt and 1/r²
    (:func:`inverse_square_factor`).  A shadow edge is thus placed to
    ~2^-bisections of a half-segment instead of a whole one: the midpoint
    rule's error on a thin shaft (lit over a few segments) is of the order
    of one segment over the shaft's lit length.  Features that lie wholly
    between two of the three test points are still missed (or counted whole).
    The working reference (DESIGN §2); cost ≈ 2 + bisections·(crossings)
    traces per segment."""
    n = dr.width(cap.d)
    sigma_t = color(params.medium.sigma_t)
    t_of = _bisection_steps(params, cap, steps, spacing)
    n_steps, inv_steps = step_count(steps)
    n_bis = opaque_scalar(mi.UInt32, bisections)
    approach = None if params.light.position is None else closest_approach(params, cap)

    # the ray's end lies on a surface, and a shadow ray from the rounded end
    # point may start behind it (a light inside a closed box leaked through
    # its faces, random seeds 43 and 98): the last test point is
    # END_NUDGE of a segment (and 1e-5 of its distance) before it
    t_first, t_last = t_of(mi.Float(0.0)), t_of(mi.Float(n_steps))
    t_test_max = dr.minimum(t_last - END_NUDGE * (t_last - t_first) * inv_steps,
                            t_last * (1.0 - 1e-5))

    def lit(t, active=True, before=False):
        """ℓ(t), a lit verdict where ℓ was not lit ``before`` (at the previous
        test point; False: always) confirmed by a shifted shadow ray
        (:func:`~integrators.core.light_transport.visible_confirmed`): where ℓ rises and inside
        the bisections
        are the only places where a ray slipping through a mesh crack adds
        light."""
        pt = point_terms(params, cap, dr.minimum(t, t_test_max), active)
        seen = visible_confirmed(params, pt.x, pt.wo, pt.dist, pt.t_in, pt.t_out, active,
                                 confirm=~mi.Bool(before))
        return seen & (dr.max(pt.L_light) > 0.0)

    def crossing(lo, hi, lit_lo, active):
        """The t in [lo, hi] where ℓ changes (it is ``lit_lo`` at lo)."""
        def body(i, lo, hi):
            m = 0.5 * (lo + hi)
            same = lit(m, active) == lit_lo
            return i + 1, dr.select(same, m, lo), dr.select(same, hi, m)
        _, lo, hi = dr.while_loop(state=(mi.UInt32(0), lo, hi),
                                  cond=lambda i, lo, hi: active & (i < n_bis), body=body)
        return 0.5 * (lo + hi)

    def half(a, b, lit_a, lit_b):
        """The lit interval of [a, b] and its contribution."""
        change = lit_a != lit_b
        c = crossing(a, b, lit_a, change)
        lo = dr.select(change & ~lit_a, c, a)
        hi = dr.select(change & lit_a, c, b)
        on = lit_a | lit_b
        tm = 0.5 * (lo + hi)
        w = segment_weight(sigma_t, lo, hi) * inverse_square_factor(approach, lo, hi, tm)
        value = point_terms(params, cap, tm, on).radiance * w
        return dr.select(on & (hi > lo), value, 0.0)

    def body(k, L, lit_a):
        s = mi.Float(k)
        a, b = t_of(s), t_of(s + 1)
        m = 0.5 * (a + b)
        lit_m = lit(m, before=lit_a)
        lit_b = lit(b, before=lit_m)
        L += half(a, m, lit_a, lit_m) + half(m, b, lit_m, lit_b)
        return k + 1, L, lit_b

    _, L, _ = dr.while_loop(
        state=(mi.UInt32(0), dr.zeros(mi.Color3f, n), lit(t_first)),
        cond=lambda k, L, lit_a: k < n_steps,
        body=body,
    )
    return L
