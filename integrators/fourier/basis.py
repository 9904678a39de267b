"""Fourier-basis prefiltering of a rectified shadow map (Klehm et al. 2014, §3).

The kernel of the ``fourier_filter`` method.  In rectified space every
shadow-map row is one epipolar slice; texel ``i = 0..n-1`` of a row holds the
normalised depth ``z_i ∈ [0, 1]`` of the first blocker on light ray ``i``
(1 = nothing blocks).  A view ray of the slice has one constant depth ``z_r``
and covers the texels ``[0, j]``.

The shadow test (§3.1, Eq. 5)
-----------------------------
``V_{z_i}(z_r) = 1`` if ``z_r − z_i ≤ 0`` else ``0``; written as a function of
``d = z_r − z_i ∈ [−1, 1]`` it is ``V = 0.5 − 0.5·sign(d)``.

The expansion (Eqs. 8–10, Annen et al. 2007)
--------------------------------------------
``−0.5·sign(d)`` is continued to the odd square wave of **period 2** in ``d``
(half period = the whole depth range [0, 1]; ``π d`` covers ``[−π, π]``).  Its
Fourier series has only odd sine harmonics::

    sign(d) = (4/π) Σ_{k≥1} sin(c_k d)/(2k − 1),     c_k = π (2k − 1)

so, truncated to ``K = M/2`` harmonics and expanded with
``sin(c(z_r − z_i)) = sin(c z_r) cos(c z_i) − cos(c z_r) sin(c z_i)``::

    V_{z_i}(z_r) ≈ 0.5 − 2 Σ_{k=1}^{K} sin(c_k (z_r − z_i)) / c_k
                 = 0.5 + Σ_{m=1}^{M} a_m(z_r) B_m(z_i)                 (Eq. 9)

    a_{2k−1}(z_r) =  (2/c_k) cos(c_k z_r),    B_{2k−1}(z_i) = sin(c_k z_i)
    a_{2k}(z_r)   = −(2/c_k) sin(c_k z_r),    B_{2k}(z_i)   = cos(c_k z_i)   (Eq. 8)

``M`` counts sines and cosines separately, as the JCGT paper does (§5; the
2014 I3D paper's "16" is this paper's 32); ``M`` must be even.  In code the
paper's 1-based ``m`` is the 0-based index ``m − 1``: even indices are the
sine bases / cosine coefficients of harmonic ``k = index // 2 + 1``.
Properties worth knowing (all tested):

- ``d = 0`` (``z_r = z_i``) reconstructs 0.5, not 1; the error is large within
  about ``1/M`` of the step and the truncated series rings (Gibbs, ≈ 9 % of
  the jump) around it (§5, Fig. 7).
- The period-2 wrap puts a *second* discontinuity at ``|d| = 1``:
  ``z_r ≈ 0`` against an unblocked texel (``z_i = 1``) reconstructs ≈ 0.5 instead
  of 1 (and ``z_r ≈ 1`` against ``z_i = 0`` gives ≈ 0.5 instead of 0), within
  about ``1/M`` of the wrap.  Mapping the depths into ``[0, 1/2]`` before
  filtering (halving them) removes this at the cost of halving the sharpness;
  ``exact_bounds`` and ``fit_depth`` below remove it in most rows for free.

Filtering (§3.1 Eq. 7, §3.3 Listings 1–2, Appendix A)
-----------------------------------------------------
With per-texel weights ``w_i`` (uniform = "average visibility" of Eq. 2/4;
``w_i`` of Eq. 11/12 = transmittance weighting of §3.2, or an angular light
factor) the filtered basis at texel ``j`` is stored *normalised*::

    B̄_m(j) = Σ_{i≤j} w_i B_m(z_i) / W(j),      W(j) = Σ_{i≤j} w_i

computed with the running mix of Listings 1–2
(``B̄ ← B̄ + (B − B̄)·w_j/W(j)``), so that ``a(z_r)·B̄(j) + 0.5`` is the weighted
*average* visibility of the texels ``[0, j]`` (Listing 4, the bracket of
Appendix A), which may be clamped to [0, 1] (Appendix A).  The un-normalised
weighted sum is ``W(j)·(a·B̄(j) + 0.5)``; with the Eq. 11 weights ``W(j)`` equals
``σ_t ∫_0^s T`` of the reference ray.

Fractional ``j``: ``j`` is a continuous texel coordinate at texel centres
(``j = 0``: texel 0 only; ``j = 2.25``: texels 0, 1, 2 and a quarter of
texel 3).  The *un-normalised* cumulative sums are interpolated linearly
between ``⌊j⌋`` and ``⌊j⌋ + 1`` — the exact integral of the piecewise-constant
texel function, i.e. hardware linear filtering of the prefix texture.

Regions (§3.3)
--------------
``regions = R`` splits every row into ``R`` runs of ``L = ⌈n/R⌉`` texels with
separate prefix sums.  What it buys and costs, measured in the tests:

- Prefilter parallelism (the paper's reason): ``R×`` more independent lanes.
- Per-pixel cost: up to ``R + 1`` lookups instead of 2 (the end of every region
  in front of ``j``), i.e. ``(R + 1)·M`` gathers.
- Memory: the same ``n·M`` floats per row, plus two floats per region.
- Accuracy: none by itself — the Fourier sum is linear, so splitting it
  changes nothing but float rounding (tested).  Accuracy comes from two
  per-region options built on the region's depth range ``[z_lo, z_hi]``
  (extensions of the paper):

  ``exact_bounds`` (evaluation, default on): if ``z_r ≤ z_lo`` the region is
  lit exactly, if ``z_r > z_hi`` exactly shadowed.  This makes unblocked rows
  exactly 1 and removes the ringing of rays in front of / behind all blockers
  of a region; it halves the mean error in the convergence test.
  ``fit_depth`` (prefilter): the basis sees ``z' = (z − z_lo)·max(1,
  1/(2 (z_hi − z_lo)))``; a region whose blockers span less than half the
  depth range lands on ``[0, 1/2]`` (no wrap-around) with a step
  ``0.5/(z_hi − z_lo)`` times sharper (error ÷ ~3 for blockers within ±0.05,
  tested); a wider one is only shifted to start at 0.  It works with
  ``regions=1`` too (per row) and costs one coefficient set per lookup
  instead of one per pixel.

``exact_bounds=False, fit_depth=False, regions=1`` is Eqs. 8–10 as published.

Everything numeric is Dr.Jit on the active variant; the ``*_reference``
functions are slow NumPy oracles (float64, direct sums, no prefix sums).
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ..core.opaque import opaque_scalar


DEFAULT_M = 32


# ---------------------------------------------------------------------------
# Basis and coefficients (Eq. 8)
# ---------------------------------------------------------------------------

def check_M(M: int) -> int:
    """Validate the number of coefficients (sines and cosines counted apart)."""
    if isinstance(M, bool) or int(M) != M or M < 2 or M % 2:
        raise ValueError(f"M = {M!r} must be an even integer >= 2 "
                         "(sine and cosine of each harmonic are counted apart).")
    return int(M)


def harmonic_frequencies(M: int) -> np.ndarray:
    """``c_k = π (2k − 1)``, ``k = 1..M/2`` (Eq. 8)."""
    return math.pi * (2.0 * np.arange(1, check_M(M) // 2 + 1) - 1.0)


def odd_harmonics(z, K: int):
    """``sin(c_k z), cos(c_k z)`` for ``k = 1..K`` as two lists of Dr.Jit arrays.

    Two ``sincos`` and then the angle-addition recurrence
    ``(2k+1)πz = (2k−1)πz + 2πz``: 4 FMAs per harmonic instead of a ``sincos``.
    In float32 its error grows ~k·ε (measured max 1.3e-5 at M = 64, 2.6e-5 at
    M = 128), the size of the error of the argument ``c_k z`` itself.
    """
    theta = dr.pi * z
    s, c = dr.sincos(theta)
    s2, c2 = dr.sincos(2.0 * theta)
    sines, cosines = [s], [c]
    for _ in range(1, K):
        s, c = dr.fma(s, c2, c * s2), dr.fma(c, c2, -(s * s2))
        sines.append(s)
        cosines.append(c)
    return sines, cosines


def basis_coefficients(z, M: int = DEFAULT_M) -> list:
    """Basis values ``[B_1(z), .., B_M(z)]`` of Eq. 8 (0-based list, Dr.Jit).

    ``B_{2k−1} = sin(c_k z)``, ``B_{2k} = cos(c_k z)``; values in [−1, 1].
    """
    sines, cosines = odd_harmonics(z, check_M(M) // 2)
    return [b for sc in zip(sines, cosines) for b in sc]


def reconstruction_weights(z_r, M: int = DEFAULT_M, harmonics=None) -> list:
    """Ray coefficients ``[a_1(z_r), .., a_M(z_r)]`` of Eq. 8 (Dr.Jit).

    ``a_{2k−1} = (2/c_k) cos(c_k z_r)``, ``a_{2k} = −(2/c_k) sin(c_k z_r)``, so
    that ``0.5 + Σ a_m(z_r) B_m(z_i)`` is the truncated series of Eq. 9.
    ``harmonics``: the :func:`odd_harmonics` of ``z_r`` if already computed.
    """
    sines, cosines = harmonics or odd_harmonics(z_r, check_M(M) // 2)
    a = []
    for c_k, s, c in zip(harmonic_frequencies(M), sines, cosines):
        a += [c * float(2.0 / c_k), s * float(-2.0 / c_k)]
    return a


def band_drop_weights(z_r, band, M: int = DEFAULT_M, harmonics=None) -> list:
    """Ray coefficients ``[d_1(z_r), .., d_M(z_r)]`` of the drop of the
    truncated series across ``[z_r − band, z_r + band]`` (Dr.Jit):
    ``0.5 + a(z_r − band)·B − 0.5 − a(z_r + band)·B = d(z_r)·B`` with
    ``d_{2k−1} = (4/c_k) sin(c_k band) sin(c_k z_r)``,
    ``d_{2k} = (4/c_k) sin(c_k band) cos(c_k z_r)`` (angle addition), so that
    one more dot product with the same basis gives it.  ``band``: a float
    (its sines on the host) or one per lane; ``harmonics``: the
    :func:`odd_harmonics` of ``z_r`` if already computed."""
    K = check_M(M) // 2
    sines, cosines = harmonics or odd_harmonics(z_r, K)
    c = harmonic_frequencies(M)
    if isinstance(band, (int, float)):
        band_sines = [float(x) for x in np.sin(c * float(band))]
    else:
        band_sines, _ = odd_harmonics(band, K)
    d = []
    for c_k, s, co, sb in zip(c, sines, cosines, band_sines):
        g = sb * float(4.0 / c_k)
        d += [g * s, g * co]
    return d


def basis_coefficients_reference(z, M: int = DEFAULT_M) -> np.ndarray:
    """NumPy oracle of :func:`basis_coefficients`: shape ``z.shape + (M,)``."""
    cz = np.asarray(z, np.float64)[..., None] * harmonic_frequencies(M)
    return np.stack([np.sin(cz), np.cos(cz)], axis=-1).reshape(cz.shape[:-1] + (M,))


def reconstruction_weights_reference(z_r, M: int = DEFAULT_M) -> np.ndarray:
    """NumPy oracle of :func:`reconstruction_weights`: ``z_r.shape + (M,)``."""
    c = harmonic_frequencies(M)
    cz = np.asarray(z_r, np.float64)[..., None] * c
    a = np.stack([2 / c * np.cos(cz), -2 / c * np.sin(cz)], axis=-1)
    return a.reshape(cz.shape[:-1] + (M,))


# ---------------------------------------------------------------------------
# Weights (§3.1 average, §3.2 Eqs. 11-12) and trivial rows
# ---------------------------------------------------------------------------

def _one_minus_exp_neg(x):
    """``1 − e^{−x}`` without cancellation for small ``x`` (Dr.Jit has no expm1)."""
    series = x * (1.0 - x * (0.5 - x * (1.0 / 6.0)))
    return dr.select(x < 1e-3, series, 1.0 - dr.exp(-x))


def transmittance_weights(optical_step, n: int, d=1.0) -> mi.TensorXf:
    """Per-texel weights ``w_i`` of Eq. 11 (``d = 1``) or Eq. 12 (``d ≠ 1``).

    ``optical_step`` = ``Δ_ref σ_t`` per row (mi.Float, one entry per row, §3.2
    reference ray); ``d`` = per-row growth factor of the step of the
    projective rectification (Eq. 12).  Texel ``i`` (0-based) spans the optical
    depths ``[τ_i, τ_{i+1}]``, ``τ_i = Δσ_t Σ_{j<i} d^j``, and
    ``w_i = e^{−τ_i} − e^{−τ_{i+1}}``, so ``W(j) = 1 − e^{−τ_{j+1}} = σ_t ∫_0^s T``.
    Returns a tensor ``(n_rows, n)``.
    """
    optical_step = mi.Float(optical_step)
    n_rows = dr.width(optical_step)
    idx = dr.arange(mi.UInt32, n_rows * n)
    n_o = opaque_scalar(mi.UInt32, n)
    row, i = idx // n_o, mi.Float(idx % n_o)
    step = dr.gather(mi.Float, optical_step, row)
    d = dr.gather(mi.Float, mi.Float(d), row) if dr.width(mi.Float(d)) > 1 else mi.Float(d)
    geometric = dr.select(dr.abs(d - 1.0) < 1e-6, i, (dr.power(d, i) - 1.0) / (d - 1.0))
    tau_i = step * geometric
    w = dr.exp(-tau_i) * _one_minus_exp_neg(step * dr.power(d, i))
    return mi.TensorXf(w, shape=(n_rows, n))


def unblocked_rows(z_rows) -> mi.Bool:
    """Rows whose texels are all unblocked (``z ≥ 1``): their visibility is
    exactly 1 for every ``z_r ≤ 1``, so the integrator can use the closed form.

    (With ``exact_bounds`` :func:`~integrators.fourier.prefilter.filtered_visibility` already
    returns exactly 1
    there; the plain Eq. 9 series gives ≈ 0.5 at ``z_r`` = 0 or 1, see module doc.)
    """
    z = mi.TensorXf(z_rows)
    n = z.shape[1]
    return dr.block_reduce(dr.ReduceOp.Min, z.array, n) >= 1.0


def unblocked_rows_reference(z_rows) -> np.ndarray:
    return np.all(np.asarray(z_rows) >= 1.0, axis=1)
