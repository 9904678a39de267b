"""Separation of the directional light's integrand kernel (Baran §6, Eq. 4):
K(γ, β) = e^{-σt γ tan(β/2)} ≈ Σ_i a_i(γ) b_i(β) by an SVD of a 64×64 sample
and its exact (Nyström) extension to every light ray and query.  Shared by
``epipolar_tree`` and ``fourier_filter``; the point/spot-light kernel is in
:mod:`integrators.epipolar_local_light`.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from .epipolar_setup import gray, light_side_gains
from .integrand_svd import SAMPLES, log1p_grid, separate_sampled_kernel, widen_empty
from .kernel_table import nystrom_sums, tabulated_terms


# --------------------------------------------------------------------------
# The separated kernel (§6, Eq. 4)
# --------------------------------------------------------------------------

def kernel(sigma_t: float):
    """K(γ, β) = e^{-σt γ tan(β/2)}: the camera- and light-side attenuation
    of a directional light joined on light ray γ (DESIGN §1), without the
    per-light-ray factor L(γ) and the per-view-ray factor 1/sin β."""
    def K(gamma, beta):
        return np.exp(-sigma_t * gamma * np.tan(beta / 2))
    return K


def _phi(x):
    """(1 − e^{-x}) / x in float64 (NumPy twin of ``cell_average``)."""
    x = np.asarray(x, np.float64)
    safe = np.where(x < 1e-12, 1.0, x)
    return np.where(x < 1e-12, 1.0, -np.expm1(-safe) / safe)


def separate_channel(sigma_t: float, gamma_max: float, beta_lo: float, beta_hi: float,
                     rank: int, tol: float):
    """Separate K(γ, β) ≈ Σ_i a_i(γ) b_i(β) over γ ∈ [0, γ_max], β ∈ [β_lo, β_hi] (§6)
    with :func:`~integrators.integrand_svd.separate_sampled_kernel`.

    Unlike the paper's uniform grid (whose rank-N error is spent where K is
    flat), the grids are uniform in log(1 + c·γ) and log(1 + σt γ_max tan(β/2))
    (c = σt tan(β_hi/2): dense where K decays fastest), and each view ray is
    normalised by its exact s_k = 1 / ∫_0^{γ_max} K(γ, β_k) dγ.  (For
    σt γ_max tan(β/2) ≫ 1, e.g. thick media or view rays near the
    anti-epipole, the uniform grid's sum errors reach 10×; this one keeps
    them at the tolerance.)  The Nyström sums are evaluated in Dr.Jit by
    :func:`exp_kernel_sum`.  Returns ``(γ grid, tan(β grid / 2), WA, WB)``."""
    G = max(float(gamma_max), 1e-30)
    beta_lo, beta_hi = widen_empty(beta_lo, beta_hi)
    x_lo, x_hi = math.tan(0.5 * beta_lo), math.tan(0.5 * beta_hi)
    c = max(sigma_t * x_hi, 1e-6 / G)
    gamma_grid, weight = log1p_grid(c, 0.0, G)
    cb = max(sigma_t * G, 1e-6)
    u = np.linspace(math.log1p(cb * x_lo), math.log1p(cb * x_hi), SAMPLES)
    x_grid = np.expm1(u) / cb

    def scale(beta):
        return 1.0 / (G * _phi(sigma_t * np.tan(0.5 * beta) * G))

    return separate_sampled_kernel(kernel(sigma_t), gamma_grid, weight, x_grid, scale,
                                   (0.0, G), (beta_lo, beta_hi), rank, tol)


def exp_kernel_sum(x: mi.Float, table: np.ndarray, weights: np.ndarray, sigma_t: float):
    """Σ_k e^{-σt x table[k]} weights[k, i] for each term i, per lane of x:
    the Nyström sums of :func:`separate_channel`
    (:func:`~integrators.kernel_table.nystrom_sums` of the exponential)."""
    tab = mi.Float(np.asarray(table, np.float32))
    # float32 range: in extreme optical depths (σt·γ_max ≳ 80) some Nyström
    # weights exceed it; their kernel factor e^{-σt x t} has underflowed to
    # 0 there, and an inf weight would turn 0 into NaN
    finite = np.clip(np.nan_to_num(weights, nan=0.0), -1e30, 1e30)
    st = dr.opaque(mi.Float, float(sigma_t))
    return nystrom_sums(dr.width(x), finite,
                        lambda k: dr.exp(-st * x * dr.gather(mi.Float, tab, k)))


def separated_kernel(params, queries, rays, rank: int, tol: float):
    """A (n, d, C, N) at the start γ_g of every light-ray interval and
    B (n, r, C, N) at the queries' own β (padded slots: 0);
    C = 1 for grey σt.  K(γ_g, β)·φ(σt tan(β/2) Δγ) is the exact mean of K
    over the interval (φ: :func:`~integrators.epipolar_setup.cell_average`,
    a per-query factor)."""
    sigma_t = np.asarray(params.medium.sigma_t, np.float64)
    channels = [0] if gray(sigma_t) else [0, 1, 2]
    gamma_max = float(dr.max(rays.gamma_max)[0])
    beta_lo, beta_hi = float(dr.min(queries.beta)[0]), float(dr.max(queries.beta)[0])
    x_lo, x_hi = math.tan(0.5 * beta_lo), math.tan(0.5 * beta_hi)
    # the per-query factor e^{-σt h_ref} multiplies the kernel's errors:
    # the automatic rank meets the tolerance after it (row_reference)
    gains = light_side_gains(sigma_t, rays.h)
    seps = [separate_channel(float(sigma_t[c]), gamma_max, beta_lo, beta_hi, rank,
                             tol / gains[c]) for c in channels]
    N = max(s[2].shape[1] for s in seps)
    C = len(channels)
    _, gamma = rays.positions(0.0)   # cell starts: φ in the query terms averages K
    tan_half = dr.tan(0.5 * queries.beta)   # only at the queries; padded slots stay 0
    A = dr.zeros(mi.Float, dr.width(gamma) * C * N)
    B = dr.zeros(mi.Float, queries.n * queries.r * C * N)
    lane_a = dr.arange(mi.UInt32, dr.width(gamma)) * (C * N)
    lane_b = queries.slot * (C * N)
    for c, (ch, (g_grid, x_grid, WA, WB)) in enumerate(zip(channels, seps)):
        st = float(sigma_t[ch])
        a_terms = tabulated_terms(gamma, 0.0, gamma_max, st * float(np.max(x_grid)),
                                  lambda x: exp_kernel_sum(x, x_grid, WA, st))
        b_terms = tabulated_terms(tan_half, x_lo, x_hi, st * gamma_max,
                                  lambda x: exp_kernel_sum(x, g_grid, WB, st))
        for i in range(WA.shape[1]):
            dr.scatter(A, a_terms[i], lane_a + c * N + i)
            dr.scatter(B, b_terms[i], lane_b + c * N + i)
    return (mi.TensorXf(A, shape=(queries.n, rays.d, C, N)),
            mi.TensorXf(B, shape=(queries.n, queries.r, C, N)))
