"""The NumPy oracle of the partial-sum tree (a direct sum per query), random
problems for tests and a micro-benchmark.
"""
from __future__ import annotations

import statistics
import time

import drjit as dr
import numpy as np

from ..epipolar.blockers import BlockerModes
from .partial_sum_tree import integrate_slices, jt, problem_layout, split_modes, to_numpy


def _reference_layout(x, n, length, has_N):
    """NumPy factor as (n|1, length, C[, N]) float64."""
    a = to_numpy(x)
    if has_N and a.ndim == 2:
        a = a[None]
    if a.ndim == 2 + has_N:
        a = np.expand_dims(a, 2)
    return a


def integrate_slices_reference(D, S_modes, A, B, *, L=None, r_count=None, d_count=None,
                               delta_gamma=1.0) -> np.ndarray:
    """Slow NumPy oracle: the direct O(r·d) sum of Eq. 3 per slice.

    Defines the semantics (module docstring): V(γ, β) = 1 − Σ w_m over the
    modes with w_m ≠ 0 and ⌈β_m⌉ ≤ β (applied *before* the query at ⌈β_m⌉),
    out[β] = Δγ Σ_i B_i(β) Σ_γ A_i(γ) L(γ) V(γ, β) clip(clip(D, 0, d) − γ, 0, 1).
    float64 inside, float32 result (n, r) or (n, r, C)."""
    lay = problem_layout(D, S_modes, A, B, L)
    Dn = np.nan_to_num(to_numpy(D), nan=0.0)
    n, r = Dn.shape
    beta_in, weight_in, (_, d, M) = split_modes(S_modes)
    beta = to_numpy(beta_in).reshape(n, d, M)
    weight = (np.ones((n, d, M)) if weight_in is None
              else to_numpy(weight_in).reshape(n, d, M))
    beta = np.where(np.isnan(beta), np.inf, beta)
    A4, B4 = _reference_layout(A, n, d, True), _reference_layout(B, n, r, True)
    L3 = np.ones((1, d, 1)) if L is None else _reference_layout(L, n, d, False)
    C = lay.C
    r_cnt = np.full(n, r) if r_count is None else np.clip(to_numpy(r_count, np.int64), 0, r)
    d_cnt = np.full(n, d) if d_count is None else np.clip(to_numpy(d_count, np.int64), 0, d)

    out = np.zeros((n, r, C))
    views = np.arange(r)
    for s in range(n):
        r_s, d_s = int(r_cnt[s]), int(d_cnt[s])
        g = np.arange(d_s)
        # V[β, γ]: remaining fraction of light ray γ at view ray β.
        onset = np.maximum(np.ceil(beta[s, :d_s]), 0.0)                  # (d_s, M)
        applied = onset[None, :, :] <= views[:r_s, None, None]            # (r_s, d_s, M)
        V = 1.0 - (applied * weight[s, :d_s][None]).sum(-1)
        cover = np.clip(np.clip(Dn[s, :r_s], 0, d_s)[:, None] - g[None, :], 0.0, 1.0)
        a = A4[s % A4.shape[0], :d_s] * L3[s % L3.shape[0], :d_s][..., None]  # (d_s, C', N)
        a = np.broadcast_to(a, (d_s, C, A4.shape[3]))
        Bs = np.broadcast_to(B4[s % B4.shape[0], :r_s], (r_s, C, B4.shape[3]))
        inner = np.einsum("bg,gcn->bcn", V * cover, a)
        out[s, :r_s] = delta_gamma * (Bs * inner).sum(-1)
    out = out.astype(np.float32)
    return out if lay.coloured else out[..., 0]


# --------------------------------------------------------------------------
# Benchmark (not a test)
# --------------------------------------------------------------------------

def random_problem(n_slices, d, r, N, *, seed=0, blocked_fraction=0.5,
                   modes=1, per_slice_L=True):
    """A random problem in the documented shapes (NumPy), for tests/bench.

    About ``blocked_fraction`` of the light rays are blocked inside the view."""
    rng = np.random.default_rng(seed)
    D = rng.uniform(-0.1 * d, 1.1 * d, (n_slices, r)).astype(np.float32)
    beta = rng.uniform(0, r / blocked_fraction, (n_slices, d, modes)).astype(np.float32)
    if modes == 1:
        S = np.floor(beta[..., 0])
    else:
        w = rng.uniform(0, 1, (n_slices, d, modes))
        S = BlockerModes(np.floor(beta), (w / w.sum(-1, keepdims=True)).astype(np.float32))
    A = rng.uniform(0.1, 1.0, (1, d, N)).astype(np.float32)
    B = rng.uniform(-1.0, 1.0, (1, r, N)).astype(np.float32)
    L = rng.uniform(0.5, 1.0, (n_slices, d)).astype(np.float32) if per_slice_L else None
    return D, S, A, B, L


def bench_tree(n_slices=1024, d=1024, r=1024, N=3, *, repeats=3, seed=0) -> float:
    """Warm median wall time [s] of :func:`~integrators.tree.partial_sum_tree.integrate_slices`
    (all steps:
    counting, termination lists, sweep) on a random problem with half of the
    light rays blocked inside the view and a per-slice light factor L.

    Inputs are uploaded first; the first (compiling) run is not timed."""
    D, S, A, B, L = random_problem(n_slices, d, r, N, seed=seed)
    D, S, A, B, L = (jt.TensorXf(x) for x in (D, S, A, B, L))
    dr.eval(D, S, A, B, L)
    times = []
    for k in range(repeats + 1):
        dr.sync_thread()
        t0 = time.perf_counter()
        res = integrate_slices(D, S, A, B, L=L)
        dr.eval(res)
        dr.sync_thread()
        if k:
            times.append(time.perf_counter() - t0)
    return statistics.median(times)
