"""In-scattering of one lit section of a view ray (Yusov 2013, "Solution to
Inscattering Integral" and "Volumetric Shadows").

A view ray ``x(t) = o + t·ω`` is cut by the min/max tree into sections
``[t_a, t_b]`` that are wholly lit (or wholly shadowed, which add nothing);
on each lit section the light's colour is constant (one tree node), so the
section adds ``colour · I(t_a, t_b)`` with ``I`` the unit-colour integral

    I(t_a, t_b) = ∫_{t_a}^{t_b} σs f_p(θ(t)) g(x(t)) e^{-σt t} e^{-σt τ(x(t))} dt.

* Directional light (talk: Hoffman & Preetham's closed form): ``θ`` and
  ``g = 1`` are constant along the ray, so ``I = σs f_p(θ) ∫ e^{-σt t - σt τ(t)} dt``.
  The light-side path ``τ(t)`` to the medium box along ``w_l`` is the minimum
  of three linear functions of ``t`` (one per slab of the box), so the
  integral is a sum of at most four exponential pieces, each exact
  (:func:`directional_section`).  The talk's unbounded medium is the case
  ``τ ≡ const``.
* Point / spot light inside the medium: ``g = 1/r²`` and ``τ = r``, the
  distance to the light.  With ``h`` the ray's closest distance to the light
  and ``S = t − t₀`` the signed position along the ray from the closest point
  (talk: ``L(cam→end) = L(S_C) − e^{−σt·len} L(S_O)``), the substitution
  ``S = h tan φ`` gives

      I(t_a, t_b) = σs e^{-σt t₀} / h · [C(h, φ_a) − C(h, φ_b)],
      C(h, φ) = ∫_φ^{π/2} f_p(φ') e^{-σt h (tan φ' + sec φ')} dφ',

  a bounded, smooth, decreasing function of ``(h, φ)``.  The talk tabulates
  ``L[h, S]`` itself; here the factors ``e^{-σt t₀}`` and ``1/h`` are taken
  out analytically and the angle ``φ = atan(S/h)`` replaces ``S``, which
  keeps the table's dynamic range finite near the light.  :class:`PointTable`
  holds ``C`` on an ``(h, φ)`` grid (resolution a property) and reads it
  bilinearly; a section shorter than a few table cells in ``φ`` integrates
  ``C``'s integrand by Simpson's rule instead (the difference of two nearby
  reads is all interpolation error);
  :func:`point_table_reference` is the float64 quadrature it is tested
  against, :func:`point_section_reference` direct quadrature of ``I``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.light_transport import color, phase_eval
from ..core.opaque import floats, point, reciprocal, scalar, vector


#: |k·L| below which ∫ e^{-k s} ds uses its Taylor series
SERIES_LIMIT = 1e-3
#: fine quadrature points of the table's cumulative integral over φ
TABLE_QUADRATURE = 8192


def exp_segment(k, a, b, log_scale=0.0):
    """``e^{log_scale} ∫_a^b e^{-k s} ds`` for any real ``k`` (also ``k ≤ 0``),
    stable as ``k·(b−a) → 0``; the exponent is taken at the end where the
    integrand is largest, so nothing overflows when the integrand is ≤ 1."""
    L = b - a
    neg = k < 0
    x = dr.abs(k) * L
    small = x < SERIES_LIMIT
    safe = dr.select(small, 1.0, x)
    phi = dr.select(small, 1 - 0.5 * x + x * x * (1.0 / 6.0), (1 - dr.exp(-x)) / safe)
    start = dr.select(neg, b, a)
    return dr.exp(log_scale - k * start) * L * phi


# --------------------------------------------------------------------------
# directional light
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class BoxPath:
    """Per ray: the light-side path to the medium box, ``τ(t) = min_i (a_i +
    b_i t)`` (one linear function per axis; axes the light runs parallel to
    are left out with ``a = +big``)."""
    a: tuple
    b: tuple


#: stand-in for the path length along an axis the light never leaves through
NO_EXIT = 1e30


def box_path(params, o: mi.Point3f, omega: mi.Vector3f) -> BoxPath:
    """τ(t) along rays ``o + t ω`` toward the directional light ``w_l``.
    A rotated or sheared box (``MediumParams.to_local``) is the cube
    ``[-1, 1]³`` in its own frame, where the same per-axis exits hold (the
    path length along the unit ``w_l`` is the parameter of the line, the
    same in both frames)."""
    if params.medium.boundary != "box":
        raise ValueError("box_path: the medium's boundary is not a box")
    w = np.asarray(params.light.direction, dtype=np.float64)
    lo, hi = params.medium.bounds_min, params.medium.bounds_max
    M = params.medium.to_local
    if M is not None:
        rows = [vector(M[i, :3]) for i in range(3)]
        o = mi.Point3f(*(dr.dot(rows[i], mi.Vector3f(o)) + scalar(M[i, 3]) for i in range(3)))
        omega = mi.Vector3f(*(dr.dot(rows[i], omega) for i in range(3)))
        w = M[:, :3] @ w
        lo, hi = -np.ones(3), np.ones(3)
    a, b = [], []
    for i in range(3):
        if abs(w[i]) < 1e-12:
            a.append(mi.Float(NO_EXIT))
            b.append(mi.Float(0.0))
            continue
        bound, inv_w = scalar(hi[i] if w[i] > 0 else lo[i]), reciprocal(w[i])
        a.append((bound - o[i]) * inv_w)
        b.append(-omega[i] * inv_w)
    return BoxPath(a=tuple(a), b=tuple(b))


def _sort3(x, y, z):
    lo = dr.minimum(dr.minimum(x, y), z)
    hi = dr.maximum(dr.maximum(x, y), z)
    return lo, x + y + z - lo - hi, hi


def directional_section(sigma_t: mi.Color3f, path: BoxPath, t_a, t_b) -> mi.Color3f:
    """``∫_{t_a}^{t_b} e^{-σt (t + τ(t))} dt`` exactly (τ piecewise linear,
    :class:`BoxPath`); ``σs f_p E`` is the caller's per-ray factor."""
    (a0, a1, a2), (b0, b1, b2) = path.a, path.b

    def cross(ai, bi, aj, bj):
        den = bi - bj
        ok = dr.abs(den) > 1e-12
        c = (aj - ai) / dr.select(ok, den, 1.0)
        return dr.clip(dr.select(ok, c, t_a), t_a, t_b)

    c0, c1, c2 = _sort3(cross(a0, b0, a1, b1), cross(a0, b0, a2, b2), cross(a1, b1, a2, b2))
    edges = (t_a, c0, c1, c2, t_b)
    out = dr.zeros(mi.Color3f, dr.width(t_a) if dr.width(t_a) > 1 else dr.width(a0))
    for p, q in zip(edges[:-1], edges[1:]):
        m = 0.5 * (p + q)
        taus = [ai + bi * m for ai, bi in ((a0, b0), (a1, b1), (a2, b2))]
        use0 = (taus[0] <= taus[1]) & (taus[0] <= taus[2])
        use1 = ~use0 & (taus[1] <= taus[2])
        a = dr.select(use0, a0, dr.select(use1, a1, a2))
        b = dr.select(use0, b0, dr.select(use1, b1, b2))
        # on this piece τ = a + b t; points past the box exit (never for a
        # camera ray inside the box) get τ = 0 through the clamp below
        neg = (a + b * m) < 0
        a, b = dr.select(neg, 0.0, a), dr.select(neg, 0.0, b)
        out += exp_segment(sigma_t * (1.0 + b), p, q, log_scale=-sigma_t * a)
    return out


def directional_section_reference(sigma_t, o, omega, w_l, bmin, bmax, t_a, t_b, n=20001):
    """Float64 quadrature (composite Simpson) of ``∫ e^{-σt (t + τ(t))} dt``,
    ``τ`` the exit distance from ``o + tω`` along ``w_l`` (one ray)."""
    t = np.linspace(t_a, t_b, n)
    x = np.asarray(o)[None] + t[:, None] * np.asarray(omega)[None]
    w = np.asarray(w_l, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (np.asarray(bmin)[None] - x) / w[None]
        t1 = (np.asarray(bmax)[None] - x) / w[None]
    tau = np.nanmin(np.where(np.isfinite(np.maximum(t0, t1)), np.maximum(t0, t1), np.inf), axis=1)
    f = np.exp(-np.asarray(sigma_t)[None] * (t + np.maximum(tau, 0))[:, None])
    h = (t_b - t_a) / (n - 1)
    wts = np.ones(n)
    wts[1:-1:2], wts[2:-1:2] = 4, 2
    return (wts[:, None] * f).sum(0) * h / 3


# --------------------------------------------------------------------------
# point and spot lights: the 2-D table C(h, φ)
# --------------------------------------------------------------------------


def phase_of_phi(params, phi) -> mi.Color3f:
    """f_p at the point ``S = h tan φ`` of a ray: the direction to the light
    makes ``cos θ = −sin φ`` with the ray (Mitsuba's ``wi = −ω``)."""
    phi = mi.Float(phi)
    s, c = dr.sincos(phi)
    omega = mi.Vector3f(0.0, 0.0, 1.0)
    wo = mi.Vector3f(c, 0.0, -s)
    return phase_eval(params, omega, wo)


def phase_of_phi_numpy(params, phi: np.ndarray) -> np.ndarray:
    v = phase_of_phi(params, floats(phi)) + dr.zeros(mi.Color3f, len(phi))
    return np.stack([np.array(v[c], dtype=np.float64) for c in range(3)], axis=1)


def point_table_reference(params, h: np.ndarray, phi: np.ndarray,
                          n: int = TABLE_QUADRATURE) -> np.ndarray:
    """``C(h, φ) = ∫_φ^{π/2} f_p(φ') e^{-σt h (tan φ' + sec φ')} dφ'``
    (len(h), len(phi), 3) in float64: cumulative trapezoid quadrature from
    π/2 down on ``n`` points, per channel."""
    sigma = np.asarray(params.medium.sigma_t, dtype=np.float64)
    grid = np.linspace(-math.pi / 2, math.pi / 2, n)
    P = phase_of_phi_numpy(params, grid)                                    # (n, 3)
    # tan φ' + sec φ' = tan(φ'/2 + π/4) grows from 0 (φ' = -π/2) to ∞ (π/2)
    ts = np.tan(0.5 * grid[:-1] + 0.25 * math.pi)
    h = np.asarray(h, dtype=np.float64)
    out = np.zeros((len(h), len(phi), 3))
    done = {}
    for c in range(3):
        key = (float(sigma[c]), P[:, c].tobytes())
        if key in done:                      # grey media: one channel does
            out[:, :, c] = out[:, :, done[key]]
            continue
        done[key] = c
        q = P[None, :-1, c] * np.exp(-sigma[c] * h[:, None] * ts[None, :])
        q = np.concatenate([q, np.zeros((len(h), 1))], axis=1)          # Q(π/2) = 0
        seg = 0.5 * (q[:, 1:] + q[:, :-1]) * np.diff(grid)[None]
        C = np.concatenate([np.cumsum(seg[:, ::-1], axis=1)[:, ::-1], np.zeros((len(h), 1))],
                           axis=1)
        for i in range(len(h)):
            out[i, :, c] = np.interp(phi, grid, C[i])
    return out


@dataclass(frozen=True, eq=False)
class PointTable:
    """``C(h, φ)`` on ``n_h × n_phi`` nodes: ``h ∈ [0, h_max]``,
    ``φ ∈ [−π/2, π/2]``; read bilinearly (:meth:`lookup`)."""
    h_max: float
    n_h: int
    n_phi: int
    values: np.ndarray = field(repr=False)     # (n_h, n_phi, 3) float64
    texture: object = field(repr=False, default=None)
    params: object = field(repr=False, default=None)   # for the phase function

    @property
    def cell(self) -> float:
        """Node spacing in φ."""
        return math.pi / (self.n_phi - 1)

    def lookup(self, h, phi) -> mi.Color3f:
        u = (dr.clip(phi * (1 / math.pi) + 0.5, 0.0, 1.0) * (self.n_phi - 1) + 0.5) / self.n_phi
        v = (dr.clip(h * scalar(1 / self.h_max), 0.0, 1.0) * (self.n_h - 1) + 0.5) / self.n_h
        out = self.texture.eval(mi.Point2f(u, v))
        return mi.Color3f(out[0], out[1], out[2])


def point_table(params, resolution: int, h_max: float | None = None) -> PointTable:
    """Tabulate ``C`` for the scene's medium and phase function."""
    if h_max is None:
        h_max = params.scene_extent
    n_h, n_phi = int(resolution), int(resolution)
    h = np.linspace(0.0, h_max, n_h)
    phi = np.linspace(-math.pi / 2, math.pi / 2, n_phi)
    values = point_table_reference(params, h, phi)
    tex = mi.Texture2f(mi.TensorXf(floats(values), shape=values.shape), use_accel=False,
                       filter_mode=dr.FilterMode.Linear, wrap_mode=dr.WrapMode.Clamp)
    return PointTable(h_max=float(h_max), n_h=n_h, n_phi=n_phi, values=values, texture=tex,
                      params=params)


@dataclass(frozen=True, eq=False)
class PointRay:
    """Per ray: closest distance ``h`` to the light and the ray parameter
    ``t0`` of the closest point."""
    h: mi.Float
    t0: mi.Float


#: sections shorter than this many table cells in φ use Simpson's rule
SIMPSON_CELLS = 4.0
#: largest exponent of e^{-σt t0} (its partner C then underflows anyway)
MAX_EXPONENT = 80.0
#: smallest h [relative to the scene size] a ray may pass the light at
MIN_H = 1e-6


def point_ray(params, o: mi.Point3f, omega: mi.Vector3f) -> PointRay:
    q = mi.Vector3f(point(params.light.position) - o)
    t0 = dr.dot(q, omega)
    h = dr.maximum(dr.norm(q - omega * t0), scalar(MIN_H * params.scene_extent))
    return PointRay(h=h, t0=t0)


def point_section(sigma_t: mi.Color3f, table: PointTable, ray: PointRay, t_a, t_b) -> mi.Color3f:
    """``∫_{t_a}^{t_b} f_p e^{-σt (t + r)} / r² dt`` from two table reads
    (``σs`` and the light's colour are the caller's)."""
    phi_a = dr.atan2(t_a - ray.t0, ray.h)
    phi_b = dr.atan2(t_b - ray.t0, ray.h)
    C_a, C_b = table.lookup(ray.h, phi_a), table.lookup(ray.h, phi_b)
    # sections shorter than a table cell: Simpson's rule on the integrand of C
    # itself (the difference of two table reads would be all interpolation error)
    short = (phi_b - phi_a) < SIMPSON_CELLS * table.cell
    phi_m = 0.5 * (phi_a + phi_b)
    # Simpson's integrand carries e^{-σt t0} in its exponent, e^{-σt (t + r)}:
    # on a ray leaving the light far behind it (t0 << 0, the anti-epipole of
    # a light outside the fog), C's integrand alone underflows float32 over a
    # short section while the product is a normal number
    simpson = (phi_b - phi_a) * (1.0 / 6.0) * (
        integrand_of_c(table.params, sigma_t, ray.h, phi_a, ray.t0)
        + 4.0 * integrand_of_c(table.params, sigma_t, ray.h, phi_m, ray.t0)
        + integrand_of_c(table.params, sigma_t, ray.h, phi_b, ray.t0))
    # a ray starting far past the light (t0 << 0) gets C ≈ 0: keep e^{-σt t0} finite
    scale = dr.exp(dr.minimum(-sigma_t * ray.t0, MAX_EXPONENT))
    return dr.select(short, simpson, scale * (C_a - C_b)) / ray.h


def integrand_of_c(params, sigma_t, h, phi, t0=None) -> mi.Color3f:
    """``f_p(φ) e^{-σt h (tan φ + sec φ)}``, the integrand of ``C``
    (``tan φ + sec φ = tan(φ/2 + π/4)``); with ``t0``, times
    ``e^{-σt t0}`` inside the exponential (``e^{-σt (t + r)}``: no
    underflow where that product is a normal number)."""
    ts = dr.minimum(dr.tan(0.5 * phi + 0.25 * math.pi), 1e30)
    x = h * ts if t0 is None else dr.maximum(h * ts + t0, 0.0)
    return phase_of_phi(params, phi) * dr.exp(-sigma_t * x)


def point_section_reference(params, o, omega, t_a, t_b, n=20001) -> np.ndarray:
    """Float64 Simpson quadrature of the same integral for one ray."""
    t = np.linspace(t_a, t_b, n)
    p_l = np.asarray(params.light.position, dtype=np.float64)
    x = np.asarray(o)[None] + t[:, None] * np.asarray(omega)[None]
    r_vec = p_l[None] - x
    r = np.linalg.norm(r_vec, axis=1)
    sin_phi = -(r_vec @ np.asarray(omega)) / r        # wo·ω = −sin φ (phase_of_phi)
    phi = np.arcsin(np.clip(sin_phi, -1, 1))
    P = phase_of_phi_numpy(params, phi)
    sigma = np.asarray(params.medium.sigma_t, dtype=np.float64)
    f = P * np.exp(-sigma[None] * (t + r)[:, None]) / (r * r)[:, None]
    hstep = (t_b - t_a) / (n - 1)
    wts = np.ones(n)
    wts[1:-1:2], wts[2:-1:2] = 4, 2
    return (wts[:, None] * f).sum(0) * hstep / 3


def sigma_colour(params) -> mi.Color3f:
    return color(params.medium.sigma_t)
