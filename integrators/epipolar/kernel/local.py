"""The separated kernel of a point or spot light (Baran et al. 2010 §9;
DESIGN §1): the geometry is in :mod:`integrators.epipolar`'s docstring.

Kernel separation (:func:`~integrators.epipolar.kernel.local.separate_local_channel`,
:class:`~integrators.epipolar.kernel.local.LocalSeparation`)
----------------------------------------------------------------------------
K is sampled as in the directional case (log-spaced grids, γ-quadrature
weights, each view ray normalised), SVD'd and extended exactly (Nyström)
in Dr.Jit.  K only matters where queries use it (x ≤ x_max, the largest x
of a query's end point); beyond, the exponent is continued linearly in x
(C¹), which keeps K smooth and of low rank on the whole rectangle
(:func:`~integrators.epipolar.kernel.local.attenuation_exponent`).  Each leaf holds the mean of
K over its
interval, integrated in the variable E (exact for a pure exponential --
K near the eye -- and for E bending within the interval, toward the
anti-epipole), with the phase at the interval's e^{-E}-weighted centroid
(:meth:`LocalKernel.cell_mean`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from ...core.host_reads import host_reductions, row_extremes
from ...core.light_transport import phase_eval, scalar
from ...core.opaque import Divisor, floats, opaque_scalar
from ..light_factor import LOCAL_LIGHT_SIDE_RANGE
from ..light_rays.local import LocalLightRays, light_ray_range
from ..queries import EpipolarQueries, frame_memo
from .separation import SeparatedChannel
from .svd import log1p_grid, separate_sampled_kernel, widen_empty
from .table import nystrom_sums, tabulated_terms


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


#: phase signature -> what was read of that phase function on the host (the
#: isotropic value, the table); kept across frames, a few phase functions
_PHASE_MEMO: dict = {}
_PHASE_MEMO_SIZE = 8


def _phase_memo(params, name: str, make):
    """``make()``, once per phase function and ``name``: keyed by the
    medium's :attr:`~integrators.core.scene_params.MediumParams.phase_signature`
    (its class and parameter values), so that a frame of an unchanged phase
    function reads nothing back (made anew where there is no signature)."""
    signature = getattr(params.medium, "phase_signature", ())
    if not signature:
        return make()
    key = (signature, name)
    if key not in _PHASE_MEMO:
        if len(_PHASE_MEMO) >= _PHASE_MEMO_SIZE:
            _PHASE_MEMO.pop(next(iter(_PHASE_MEMO)))
        _PHASE_MEMO[key] = make()
    return _PHASE_MEMO[key]


def _isotropic_value(params):
    """The constant f_p of an isotropic medium, else None."""
    if params.medium.phase_kind != "isotropic":
        return None
    return _phase_memo(params, "isotropic",
                       lambda: float(phase_of_angle(params, mi.Float(1.0))[0]))


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

    def make():
        t = phase_of_angle_numpy(params, np.linspace(0.0, np.pi, n))
        return np.append(t, t[-1])
    table = _phase_memo(params, "table", make)

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
    point/spot light model's ``ray_kernel``.  The light ray's start and
    width are made where they are read, from its row's evaluated arrays
    (as :meth:`~integrators.epipolar.light_rays.layout.EqualLightRays.positions`
    gives them at lane t): no kernel of their own."""
    L, x_max = float(queries.frame.light_distance), query_x_max(queries)
    per = Divisor(rays.d)

    def kernel(t, tan):
        s, g = per.divmod(t)
        return local_kernel(params, sigma_t, L, x_max, tan, rays.position(s, g, 0.0),
                            dr.gather(mi.Float, rays.delta_gamma, s))
    return kernel


def separate_local_channel(params, sigma_t: float, L: float, x_max: float, gamma_lo: float,
                           gamma_hi: float, beta_lo: float, beta_hi: float, rank: int,
                           tol: float, band_tan: float = 0.0):
    """Separate K(γ, β) ≈ Σ_i a_i(γ) b_i(β) over [γ_lo, γ_hi] × [β_lo, β_hi]
    with :func:`~integrators.epipolar.kernel.svd.separate_sampled_kernel`, as
    :func:`integrators.epipolar.kernel.separation.separate_channel` does for the
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
    x = query_x(queries.whole_frame)
    return float(min(max(float(dr.max(x)[0]), 1e-6), 1.0 - 1e-6))


def query_x(queries: EpipolarQueries) -> mi.Float:
    """x = tan(β/2) tan(γ_end/2) of every query's end point, made once per
    frame's queries (the kernel's grid and the frame's choices read its
    largest) and scheduled: evaluated by the next kernel over the queries
    (the asymptote band's test,
    :func:`~integrators.epipolar.local_query_terms.reaches_asymptote_band`,
    and :func:`lit_domain`'s reductions ask for it first) or where it is
    read."""
    def make():
        x = dr.tan(0.5 * queries.beta) * dr.tan(0.5 * queries.gamma_end)
        dr.schedule(x)
        return x
    return frame_memo(queries, ("query_x",), make)


def lit_domain(params, queries: EpipolarQueries, rays: LocalLightRays):
    """(γ_lo, γ_hi, β_lo, β_hi): the rectangle on which the separated kernel
    must be accurate -- the light rays of the rows that carry light
    (:func:`~integrators.epipolar.light_rays.local.light_ray_range`; all rows if none does) and
    the β of their
    queries, below π − γ_lo (a view ray at β reaches γ < π − β only).  A
    spot's dark rows start at γ = 0, where K is largest: a kernel separated
    to a relative tolerance over ``[0, γ_hi]`` is all error on a narrow cone
    far from the eye; and a view ray that meets no lit light ray has
    K ≈ 0 on the whole domain, which its normalisation would blow up."""
    def make():
        lit = light_ray_range(params, queries)[2]
        # with and without the lit rows: the host picks (the rows' arrays
        # copied, no kernel; the queries' reduced in one kernel)
        any_lit = bool(np.asarray(lit).any())
        rows = lit if any_lit else None
        gamma_lo = row_extremes(rays.gamma_lo, rows)[0]
        gamma_hi = row_extremes(rays.gamma_max, rows)[1]
        row_lit = dr.gather(mi.Bool, lit, queries.row) if any_lit else mi.Bool(True)
        query_x(queries)        # scheduled: evaluated with the reductions below
        seen = row_lit & (queries.beta < scalar(math.pi - gamma_lo))
        any_seen, lo_seen, hi_seen, lo_q, hi_q = host_reductions(
            (dr.any, seen), (dr.min, dr.select(seen, queries.beta, dr.inf)),
            (dr.max, dr.select(seen, queries.beta, -dr.inf)),
            (dr.min, queries.beta), (dr.max, queries.beta))
        beta_lo, beta_hi = (lo_seen, hi_seen) if any_seen else (lo_q, hi_q)
        return gamma_lo, gamma_hi, beta_lo, beta_hi
    return frame_memo(queries, ("lit_domain", params, rays), make)


@dataclass(frozen=True)
class LocalChannel(SeparatedChannel):
    """One colour channel of the §9 kernel, separated
    (:func:`separate_local_channel`), with its Dr.Jit terms
    (:func:`~integrators.epipolar.kernel.table.nystrom_sums` of :class:`LocalKernel`)."""
    kernel: LocalKernel
    c_b: float              # the b-table's warp rate σt L (γ_hi − γ_lo)
    _grids: dict = field(default_factory=dict, compare=False, repr=False)

    def grids(self) -> tuple:
        """(β grid, γ grid) as :class:`Angles`, evaluated together once."""
        if not self._grids:
            b = Angles.from_tan_half(floats(self.x_grid))
            g = Angles.of(floats(self.gamma_grid))
            dr.eval(b.tan_half, b.sin, b.cos, g.tan_half, g.sin, g.cos)
            self._grids.update(b=b, g=g)
        return self._grids["b"], self._grids["g"]

    def a_terms(self, cells, count: int, lanes: int | None = None) -> list:
        """The mean of a_i over each lattice cell, ``cells = (bounds, Δγ)``
        (:func:`interval_bounds`)."""
        bounds, delta = cells
        b_grid = self.grids()[0]
        return nystrom_sums(count, self.WA,
                            lambda k: self.kernel.cell_mean(b_grid.gather(k), bounds, delta))

    def b_terms(self, tan_half, lanes: int | None = None) -> list:
        """b_i at the queries' tan(β/2): it depends on β alone, so it is
        tabulated in tan(β/2) with the SVD grid's warp (``lanes``:
        :func:`~integrators.epipolar.kernel.table.tabulated_terms`)."""
        g_grid = self.grids()[1]

        def b_sums(x):
            b = Angles.from_tan_half(x)
            return nystrom_sums(dr.width(x), self.WB, lambda k: self.kernel.value(b, g_grid.gather(k)))
        return tabulated_terms(tan_half, self.x_lo, self.x_hi, self.c_b, b_sums, lanes)


@dataclass(frozen=True)
class LocalSeparation:
    """The point/spot light's stages of
    :func:`integrators.epipolar.kernel.separation.separate_kernel`: A is the mean of
    a_i over every cell of the light rays' lattice
    (:class:`~integrators.epipolar.light_rays.local.LocalLightRays`),
    evaluated once per cell and gathered into the rows (leaf g of row s =
    cell m_s + g).

    ``band_cells`` > 0: the kernel separated is the *banded* one -- E held
    constant in the last ``band_cells`` lattice cells before each view
    ray's asymptote γ = π − β (:func:`band_x`) -- and the sweep's sum must
    be corrected there by
    :func:`~integrators.epipolar.local_query_terms.asymptote_band_correction`.  With the
    light near the eye (L ≪ the view rays' lengths) every point farther
    than ~L/Δγ from the eye lies in those cells, so the whole rise of E
    (the camera-side transmittance) happens within ~1e-4 rad of the
    asymptote: a step along the diagonal β + γ = π that no rank-24 kernel
    resolves (random stress seeds 79, 233, 266: separation error 0.13 at rank
    24, per-query sums off by up to 5 %)."""
    #: the light-side range c of its light rays
    light_side_range = LOCAL_LIGHT_SIDE_RANGE

    band_cells: int = 0

    def band_tan(self, rays: LocalLightRays) -> float:
        """tan(w/2) of the band's width w = band_cells·Δγ (0: no band)."""
        if not self.band_cells:
            return 0.0
        return math.tan(0.5 * min(self.band_cells * float(rays.delta_gamma[0]), 3.0))

    def light_side_path(self, queries, rays: LocalLightRays):
        """L − r_in: the light side of each light ray
        (:func:`~integrators.epipolar.light_factor.light_side_extinction`)."""
        return scalar(queries.frame.light_distance) - rays.r_in

    def channel(self, params, queries, rays: LocalLightRays, sigma_t: float, rank: int,
                tol: float) -> LocalChannel:
        L = float(queries.frame.light_distance)
        # the domain first: its kernel over the queries makes their x too
        gamma_lo, gamma_hi, beta_lo, beta_hi = lit_domain(params, queries, rays)
        x_max = query_x_max(queries)
        band = self.band_tan(rays)
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
        cell = dr.minimum(dr.gather(mi.UInt32, rays.offset, s_row) + g, opaque_scalar(mi.UInt32, M - 1))
        return dr.gather(mi.Float, A_cells, cell * opaque_scalar(mi.UInt32, CN) + c)
