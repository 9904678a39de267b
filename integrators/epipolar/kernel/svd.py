"""Separation of the integrand, I(γ, β) ≈ Σ_{i<N} A_i(γ) B_i(β) (Baran et al. 2010, §6, Eq. 4).

The Fenwick-tree sweep (:mod:`integrators.tree.partial_sum_tree`) needs the
integrand as a short sum of products of a light-ray function A_i(γ) (stored
in the tree) and a view-ray function B_i(β) (multiplied into the queries).
As in §6 the integrand is sampled on a small grid (64 × 64), decomposed with
an SVD, the singular values are folded into B, and the singular vectors are
linearly upsampled to the γ and β coordinates of the integration grid --
or, by default when I is a callable, extended exactly with I itself
(:func:`extend_nystrom`), which keeps the full-resolution error at the level
of the truncation error (linear upsampling of 64 samples of the directional
kernel below leaves ≈ 5 % error near the epipole whatever N is).

N is either given or chosen as the smallest rank whose dropped singular
values have a relative energy of at most ``tol``:

    err(N) = sqrt(Σ_{k≥N} σ_k²) / sqrt(Σ_k σ_k²) = ‖I − I_N‖_F / ‖I‖_F  (on the grid).

:func:`relative_error` measures the same quantity at full resolution, where
the linear upsampling adds its own (small, for smooth integrands) error.

Directional light (DESIGN §1): on slice α a point of view ray β (angle to the
direction towards the light) and light ray γ (distance of the light ray from
the eye) lies at t = γ / sin β, so ds/dγ = 1 / sin β, and the camera- and
light-side attenuations join into e^{-σt γ tan(β/2)} times the per-light-ray
factor e^{-σt h(α, γ)} (the tree's L, not part of I).  Any phase function is
a factor of β alone.  :func:`directional_light_kernel` builds that I.  Only
NumPy: this is a 64 × 64 problem solved once per frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


#: Default number of samples per axis of the SVD grid (§6).
SAMPLES = 64


@dataclass(frozen=True)
class Separation:
    """Result of :func:`separate_integrand`.

    ``A`` (d, N): Γ_i at the requested γ; ``B`` (r, N): σ_i · B_i at the
    requested β (singular values folded in, §6); ``grid_error``: err(N), the
    relative Frobenius error of the rank-N truncation on the sample grid;
    ``error``: the achieved relative Frobenius error of A Bᵀ against I at
    the requested coordinates (measured on up to ``CHECK``² of them; equal
    to ``grid_error`` when I is a given matrix); ``singular_values``: all
    σ_k of the sampled matrix, descending."""

    A: np.ndarray
    B: np.ndarray
    error: float
    grid_error: float
    singular_values: np.ndarray

    @property
    def N(self) -> int:
        return self.A.shape[1]


def sample_grid(x, samples: int = SAMPLES) -> np.ndarray:
    """``samples`` equally spaced points spanning the range of ``x``."""
    x = np.asarray(x, np.float64)
    return np.linspace(x.min(), x.max(), samples)


def sample_integrand(I, gamma_grid, beta_grid) -> np.ndarray:
    """Matrix I[γ_j, β_k] of a vectorised callable ``I(gamma, beta)``."""
    values = I(np.asarray(gamma_grid)[:, None], np.asarray(beta_grid)[None, :])
    return np.broadcast_to(np.asarray(values, np.float64),
                           (len(gamma_grid), len(beta_grid))).copy()


def truncation_errors(sigma) -> np.ndarray:
    """err(N) for N = 0..len(sigma): relative energy of the dropped σ."""
    sigma = np.asarray(sigma, np.float64)
    tail = np.sqrt(np.maximum(np.cumsum((sigma ** 2)[::-1])[::-1], 0.0))
    total = tail[0] if sigma.size and tail[0] > 0 else 1.0
    return np.append(tail, 0.0) / total


def choose_rank(sigma, tol: float, max_N: int | None = None) -> int:
    """Smallest N ≥ 1 with err(N) ≤ tol (at most ``max_N``)."""
    errors = truncation_errors(sigma)
    ok = np.flatnonzero(errors[1:] <= tol)
    N = int(ok[0]) + 1 if ok.size else len(sigma)
    return max(1, min(N, max_N if max_N is not None else N))


def upsample(grid, columns, x) -> np.ndarray:
    """Linear interpolation of each column of ``columns`` (sampled at the
    increasing ``grid``) at ``x``; constant beyond the ends."""
    return np.stack([np.interp(x, grid, c) for c in np.asarray(columns).T], axis=-1)


def extend_linear(svd, N, grids, gamma, beta):
    """§6 as published: linear upsampling of Γ_i and σ_i B_i."""
    U, sigma, Vt = svd
    return (upsample(grids[0], U[:, :N], gamma),
            upsample(grids[1], Vt[:N].T * sigma[:N], beta))


def extend_nystrom(I, svd, N, grids, gamma, beta):
    """Exact extension of the singular vectors with the callable I:
    Γ_i(γ) = Σ_k I(γ, β_k) V_ki / σ_i and σ_i B_i(β) = Σ_j U_ji I(γ_j, β).

    Reproduces the rank-N SVD on the grid and follows I exactly along each
    axis between grid points, where linear upsampling of a kernel like
    1/sin β near the epipole loses several percent."""
    U, sigma, Vt = svd
    A = sample_integrand(I, gamma, grids[1]) @ (Vt[:N].T / sigma[:N])
    B = sample_integrand(I, grids[0], beta).T @ U[:, :N]
    return A, B


def separate_integrand(I, gamma, beta, *, N: int | None = None, tol: float = 1e-3,
                       samples: int = SAMPLES, max_N: int = 16, grid: tuple | None = None,
                       extend: str = "nystrom") -> Separation:
    """Separate I(γ, β) ≈ Σ_i A_i(γ) B_i(β) for the coordinates ``gamma`` (d,)
    and ``beta`` (r,) of the integration grid (§6, Eq. 4).

    ``I``: a vectorised callable ``I(gamma, beta)`` (sampled on ``samples`` ×
    ``samples`` points spanning the ranges of ``gamma`` and ``beta``), or an
    already sampled matrix, taken on ``grid = (gamma_grid, beta_grid)``
    (increasing; default: equally spaced over the ranges of ``gamma`` and
    ``beta``).  ``N``: the rank, or None for the smallest with
    ``grid_error ≤ tol`` -- and, with the exact extension, also ``error ≤
    tol`` -- capped at ``max_N``; terms with σ_i ≤ 1e-9 σ_0 are never kept.
    ``extend``: ``"nystrom"`` (callables only, default,
    :func:`extend_nystrom`) or ``"linear"`` (§6, :func:`extend_linear`; the
    only choice for a matrix).  Signs are fixed so that each A_i sums to
    ≥ 0 on the grid."""
    gamma = np.asarray(gamma, np.float64)
    beta = np.asarray(beta, np.float64)
    if callable(I):
        grids = grid or (sample_grid(gamma, samples), sample_grid(beta, samples))
        M = sample_integrand(I, *grids)
    else:
        M = np.asarray(I, np.float64)
        grids = grid or (sample_grid(gamma, M.shape[0]), sample_grid(beta, M.shape[1]))
        extend = "linear"
    if not np.all(np.isfinite(M)):
        raise ValueError("the sampled integrand is not finite (exclude the epipole, §6)")
    U, sigma, Vt = np.linalg.svd(M, full_matrices=False)
    rank = max(1, int(np.sum(sigma > 1e-9 * sigma[0])))
    auto = N is None
    N = min(choose_rank(sigma, tol, max_N) if auto else int(N), rank)
    if extend not in ("nystrom", "linear"):
        raise ValueError(f"extend must be 'nystrom' or 'linear', not {extend!r}")
    signs = np.where(U.sum(0) < 0, -1.0, 1.0)
    svd = (U * signs, sigma, Vt * signs[:, None])
    while True:
        if extend == "nystrom":
            A, B = extend_nystrom(I, svd, N, grids, gamma, beta)
        else:
            A, B = extend_linear(svd, N, grids, gamma, beta)
        error = _achieved_error(I, A, B, gamma, beta) if callable(I) else None
        # Automatic N with the exact extension: also the achieved error
        # (which can exceed the grid's by a few times) must meet tol.
        if not (auto and extend == "nystrom" and error > tol and N < min(max_N, rank)):
            break
        N += 1
    grid_error = float(truncation_errors(sigma)[N])
    return Separation(A, B, grid_error if error is None else error, grid_error, sigma)


#: Points per axis on which :func:`separate_integrand` measures ``error``.
CHECK = 257


def _achieved_error(I, A, B, gamma, beta) -> float:
    """:func:`relative_error` on up to CHECK × CHECK of the coordinates."""
    gi = np.unique(np.linspace(0, len(gamma) - 1, min(CHECK, len(gamma))).astype(int))
    bi = np.unique(np.linspace(0, len(beta) - 1, min(CHECK, len(beta))).astype(int))
    return relative_error(I, A[gi], B[bi], gamma[gi], beta[bi])


def relative_error(I, A, B, gamma, beta) -> float:
    """‖I − A Bᵀ‖_F / ‖I‖_F at the full-resolution coordinates (γ, β)."""
    M = sample_integrand(I, gamma, beta) if callable(I) else np.asarray(I, np.float64)
    return float(np.linalg.norm(M - np.asarray(A) @ np.asarray(B).T) / np.linalg.norm(M))


def directional_light_kernel(sigma_t: float, phase=None):
    """I(γ, β) = phase(β) · e^{-σt γ tan(β/2)} / sin β of a directional light
    (DESIGN §1); ``phase`` is a callable of β (None: 1).  σs, the light's
    irradiance and Δγ are constant factors applied elsewhere; the
    per-light-ray factor e^{-σt h(α, γ)} is the tree's L (§6)."""
    def I(gamma, beta):
        value = np.exp(-sigma_t * gamma * np.tan(beta / 2)) / np.sin(beta)
        return value * (phase(beta) if phase is not None else 1.0)
    return I


# --------------------------------------------------------------------------
# The weighted SVD of a light model's kernel (§6; both light kinds)
# --------------------------------------------------------------------------

#: extra points per axis on which the automatic rank is checked (besides the grid)
CHECK_POINTS = 193
#: largest automatic rank per colour channel (both light kinds)
MAX_RANK = 24


def log1p_grid(c: float, lo: float, hi: float, samples: int = SAMPLES):
    """``samples`` points uniform in v = log(1 + c (y − lo)) over [lo, hi]
    and the grid's quadrature weight dy/dv·Δv as a function of y."""
    v = np.linspace(0.0, math.log1p(c * (hi - lo)), samples)

    def weight(y):
        return (1.0 + c * (np.asarray(y) - lo)) / c * (v[1] - v[0])
    return lo + np.expm1(v) / c, weight


def widen_empty(lo: float, hi: float, margin: float = 1e-4) -> tuple:
    """``(lo, hi)``, widened by ``margin`` on both sides when empty (all
    queries on one view ray)."""
    if not hi > lo:
        return lo - margin, hi + margin
    return lo, hi


def separate_sampled_kernel(K, gamma_grid, weight, x_grid, scale, gamma_range: tuple,
                            beta_range: tuple, rank: int, tol: float):
    """Separate a light model's kernel K(γ, β) ≈ Σ_i a_i(γ) b_i(β) (§6) by
    the SVD of the weighted sample

        M_jk = √w_j · K(γ_j, β_k) · s_k

    on ``gamma_grid`` (quadrature weights ``weight(γ)``) and β_k = 2 atan
    ``x_grid`` (``x_grid``: tan(β/2) of the β grid); ``scale(β)`` = s
    normalises each view ray's ∫K dγ, so M's Frobenius error is the relative
    L2 error of each view ray's integrand, the quantity a sweep sums.  The
    automatic rank (``rank`` 0) is checked on the grid and on CHECK_POINTS
    uniform points of ``gamma_range`` × ``beta_range``, at most MAX_RANK.
    The exact (Nyström) extension (:func:`extend_nystrom`) gives

        a_i(γ) = Σ_k K(γ, β_k) WA_ki,   WA = V diag(1/σ) · s,
        b_i(β) = Σ_j K(γ_j, β) WB_ji,   WB = √w · U.

    Returns ``(γ grid, tan(β grid / 2), WA, WB)``."""
    beta_grid = 2.0 * np.arctan(x_grid)

    def I_w(gamma, beta):
        return np.sqrt(weight(gamma)) * K(gamma, beta) * scale(beta)

    gamma = np.concatenate([gamma_grid, np.linspace(*gamma_range, CHECK_POINTS)])
    beta = np.concatenate([beta_grid, np.linspace(*beta_range, CHECK_POINTS)])
    sep = separate_integrand(I_w, gamma, beta, N=rank or None, tol=tol,
                             grid=(gamma_grid, beta_grid), max_N=MAX_RANK)
    U, VS, sigma = sep.A[:SAMPLES], sep.B[:SAMPLES], sep.singular_values[:sep.N]
    WA = VS * scale(beta_grid)[:, None] / sigma ** 2
    WB = np.sqrt(weight(gamma_grid))[:, None] * U
    return gamma_grid, x_grid, WA, WB
