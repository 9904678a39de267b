"""Tests of the Fourier-basis prefiltering kernel (Klehm et al. 2014, §3).

Fast Dr.Jit paths against NumPy oracles, convergence of the filtered
visibility to the exact Eq. 2 average as M grows, ringing and clamping
(Appendix A), and the edge cases the integrator relies on.  Sizes are small:
the machine is shared.
"""
import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st


if mi.variant() is None:
    mi.set_variant("llvm_ad_rgb")

from integrators.fourier import basis as fb_basis
from integrators.fourier import prefilter as fb_prefilter


F32 = np.float32


def visibility(filtered, rows, j, z_r, **kw):
    """Fast filtered visibility for NumPy query arrays."""
    return fb_prefilter.filtered_visibility(
        filtered, mi.UInt32(np.asarray(rows, np.uint32)), mi.Float(np.asarray(j, F32)),
        mi.Float(np.asarray(z_r, F32)), **kw).numpy()


def blocky_rows(rng, n_rows, n, lo=0.2, hi=0.8, blockers=4):
    """Rows of piecewise-constant blockers at depths in [lo, hi], background 1."""
    z = np.ones((n_rows, n))
    for row in z:
        for _ in range(blockers):
            a = rng.integers(0, n - 8)
            row[a:a + rng.integers(4, n // 4)] = rng.uniform(lo, hi)
    return z.astype(F32)


# ---------------------------------------------------------------------------
# Eq. 8: basis and coefficients
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("M", [2, 32, 128])
def test_basis_and_coefficients_match_numpy(M):
    z = np.concatenate([[0.0, 1.0, 0.5], np.random.default_rng(0).random(61)]).astype(F32)
    B = np.stack([b.numpy() for b in fb_basis.basis_coefficients(mi.Float(z), M)], axis=-1)
    a = np.stack([x.numpy() for x in fb_basis.reconstruction_weights(mi.Float(z), M)], axis=-1)
    assert np.all(np.isfinite(B)) and np.all(np.isfinite(a))
    np.testing.assert_allclose(B, fb_basis.basis_coefficients_reference(z, M), atol=2e-5 * (1 + M / 32))
    np.testing.assert_allclose(a, fb_basis.reconstruction_weights_reference(z, M), atol=2e-6)


def test_series_is_the_truncated_square_wave_of_eq9():
    """0.5 + a(z_r)·B(z_i) = 0.5 − 2 Σ_k sin(c_k (z_r − z_i))/c_k (period 2 in d)."""
    rng = np.random.default_rng(1)
    z_r, z_i = rng.random(50), rng.random(50)
    M = 16
    lhs = 0.5 + np.sum(fb_basis.reconstruction_weights_reference(z_r, M)
                       * fb_basis.basis_coefficients_reference(z_i, M), axis=-1)
    c = fb_basis.harmonic_frequencies(M)
    rhs = 0.5 - 2 * np.sum(np.sin(np.outer(z_r - z_i, c)) / c, axis=-1)
    np.testing.assert_allclose(lhs, rhs, atol=1e-12)
    # step value at the discontinuity and wrap-around point: 0.5
    for zr, zi in [(0.3, 0.3), (0.0, 1.0), (1.0, 0.0)]:
        v = 0.5 + fb_basis.reconstruction_weights_reference(zr, M) @ fb_basis.basis_coefficients_reference(zi, M)
        assert v == pytest.approx(0.5, abs=1e-12)


@pytest.mark.parametrize("M", [0, 3, -2, 2.5, True])
def test_M_must_be_even(M):
    with pytest.raises(ValueError):
        fb_basis.check_M(M)


# ---------------------------------------------------------------------------
# Prefilter: fast == oracle
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("weights_kind, M, regions, fit_depth", [
    ("none", 32, 1, False), ("shared", 16, 3, False),
    ("rows", 32, 4, True), ("rows", 6, 2, False)])
def test_prefix_filter_matches_reference(weights_kind, M, regions, fit_depth):
    rng = np.random.default_rng(2)
    n_rows, n = 5, 37
    z = rng.random((n_rows, n)).astype(F32)
    z[rng.random(z.shape) < 0.3] = 1.0
    z[0, :5] = 0.0
    w = {"none": None, "shared": rng.random(n).astype(F32),
         "rows": rng.random((n_rows, n)).astype(F32)}[weights_kind]
    fast = fb_prefilter.prefix_filter(mi.TensorXf(z), None if w is None else mi.TensorXf(w), M,
                            regions, fit_depth)
    ref = fb_prefilter.prefix_filter_reference(z, w, M, regions, fit_depth)
    assert fast.B_bar.shape == (n_rows, n, M) and fast.W.shape == (n_rows, n)
    np.testing.assert_allclose(fast.B_bar.numpy(), ref["B_bar"], atol=2e-5)
    np.testing.assert_allclose(fast.W.numpy(), ref["W"], rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(fast.z_lo.numpy(), ref["z_lo"])
    np.testing.assert_array_equal(fast.z_hi.numpy(), ref["z_hi"])


def test_prefix_filter_zero_weights_are_nan_free():
    z = np.array([[0.0, 0.5, 1.0, 0.2, 1.0, 0.0]], F32)
    w = np.array([[0.0, 0.0, 1.0, 0.0, 2.0, 0.0]], F32)
    fast = fb_prefilter.prefix_filter(mi.TensorXf(z), mi.TensorXf(w), 8)
    ref = fb_prefilter.prefix_filter_reference(z, w, 8)
    assert np.all(np.isfinite(fast.B_bar.numpy()))
    np.testing.assert_allclose(fast.B_bar.numpy(), ref["B_bar"], atol=1e-5)
    v = visibility(fast, [0, 0, 0], [0.0, 1.5, 5.0], [0.3, 0.0, 1.0], exact_bounds=False)
    assert np.all(np.isfinite(v))


def test_prefix_filter_rejects_bad_shapes():
    with pytest.raises(ValueError):
        fb_prefilter.prefix_filter(mi.TensorXf(np.zeros((2, 4), F32)), mi.TensorXf(np.ones(3, F32)), 4)
    with pytest.raises(ValueError):
        fb_prefilter.prefix_filter(mi.TensorXf(np.zeros((2, 10), F32)), None, 4, regions=6)


# ---------------------------------------------------------------------------
# Per-pixel evaluation: fast == oracle
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("M, regions, fit_depth", [(32, 1, False), (16, 3, False), (32, 4, True)])
def test_filtered_visibility_matches_reference(M, regions, fit_depth):
    rng = np.random.default_rng(3)
    n_rows, n, q = 4, 41, 120
    z = rng.random((n_rows, n)).astype(F32)
    z[rng.random(z.shape) < 0.3] = 1.0
    w = rng.random((n_rows, n)).astype(F32)
    filtered = fb_prefilter.prefix_filter(mi.TensorXf(z), mi.TensorXf(w), M, regions, fit_depth)
    rows = rng.integers(0, n_rows, q)
    j = (rng.random(q) * (n + 4) - 2).astype(F32)       # includes j < 0 and j > n−1
    j[:6] = [0, n - 1, 12, 13, 20.5, 40.75]
    z_r = rng.random(q).astype(F32)
    z_r[:3] = [0.0, 1.0, 0.5]
    for clamp in (False, True):
        for exact_bounds in (False, True):
            fast = visibility(filtered, rows, j, z_r, clamp=clamp, exact_bounds=exact_bounds)
            ref = [fb_prefilter.filtered_visibility_reference(z[r], w[r], jj, zz, M, clamp, exact_bounds,
                                                    regions, fit_depth)
                   for r, jj, zz in zip(rows, j, z_r)]
            np.testing.assert_allclose(fast, ref, atol=1e-5)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(n=st.integers(2, 24), regions=st.integers(1, 3), fit_depth=st.booleans(),
       seed=st.integers(0, 2**31 - 1))
def test_filtered_visibility_matches_reference_property(n, regions, fit_depth, seed):
    if (regions - 1) * -(-n // regions) >= n:
        regions = 1
    rng = np.random.default_rng(seed)
    z = rng.choice([0.0, 0.25, 0.5, 1.0, rng.random()], size=(2, n)).astype(F32)
    w = rng.choice([0.0, 0.5, 1.0], size=(2, n)).astype(F32)
    w[:, 0] = 1.0
    filtered = fb_prefilter.prefix_filter(mi.TensorXf(z), mi.TensorXf(w), 8, regions, fit_depth)
    rows, j = rng.integers(0, 2, 6), (rng.random(6) * n).astype(F32)
    z_r = rng.choice([0.0, 0.25, 0.5, 1.0, rng.random()], size=6).astype(F32)
    fast = visibility(filtered, rows, j, z_r, clamp=True)
    ref = [fb_prefilter.filtered_visibility_reference(z[r], w[r], jj, zz, 8, True, True, regions, fit_depth)
           for r, jj, zz in zip(rows, j, z_r)]
    np.testing.assert_allclose(fast, ref, atol=1e-5)


# ---------------------------------------------------------------------------
# Convergence to the exact Eq. 2 average as M grows
# ---------------------------------------------------------------------------

def convergence_errors(z, weights, Ms, exact_bounds, delta=0.05, q=600, seed=4):
    """Mean and max |V̄ − V_exact| over rays at least ``delta`` from every step."""
    rng = np.random.default_rng(seed)
    n_rows, n = z.shape
    rows = rng.integers(0, n_rows, q)
    j = (rng.random(q) * (n - 1)).astype(F32)
    z_r = rng.uniform(0.1, 0.9, q).astype(F32)
    away = np.array([np.abs(z[r] - zz).min() > delta for r, zz in zip(rows, z_r)])
    rows, j, z_r = rows[away], j[away], z_r[away]
    w_np = None if weights is None else weights.numpy()
    exact = np.array([fb_prefilter.average_visibility_reference(
        z[r], None if w_np is None else w_np[r], jj, zz) for r, jj, zz in zip(rows, j, z_r)])
    out = []
    for M in Ms:
        filtered = fb_prefilter.prefix_filter(mi.TensorXf(z), weights, M)
        err = np.abs(visibility(filtered, rows, j, z_r, exact_bounds=exact_bounds) - exact)
        out.append((err.mean(), err.max()))
    return np.array(out)


@pytest.mark.parametrize("exact_bounds", [False, True])
def test_average_visibility_converges_with_M(exact_bounds):
    """§3.1 average weights; measured mean/max error at M = 16, 32, 64, 128:
    paper mode 0.014/0.062, 0.0066/0.034, 0.0034/0.016, 0.0020/0.0083;
    exact_bounds mean 0.0077, 0.0037, 0.0020, 0.0011 (error ∝ 1/M)."""
    z = blocky_rows(np.random.default_rng(5), 6, 128)
    err = convergence_errors(z, None, [16, 32, 64, 128], exact_bounds)
    mean, worst = err[:, 0], err[:, 1]
    assert np.all(mean[1:] < 0.75 * mean[:-1]), mean
    assert np.all(worst[1:] < 1.05 * worst[:-1]), worst
    assert mean[-1] < 0.005 and worst[-1] < 0.03, err[-1]


def test_transmittance_weighted_visibility_converges_with_M():
    """§3.2 Eq. 11 weights (optical depth 3 over the row)."""
    n_rows, n = 6, 128
    z = blocky_rows(np.random.default_rng(6), n_rows, n)
    w = fb_basis.transmittance_weights(mi.Float(np.full(n_rows, 3.0 / n, F32)), n)
    err = convergence_errors(z, w, [16, 32, 64, 128], exact_bounds=False)
    assert np.all(err[1:, 0] < 0.75 * err[:-1, 0]), err
    assert err[-1, 0] < 0.005 and err[-1, 1] < 0.03, err[-1]


# ---------------------------------------------------------------------------
# Ringing and clamping (§5 Fig. 7, Appendix A)
# ---------------------------------------------------------------------------

def test_ringing_overshoots_and_clamping_removes_it():
    """A planar blocker (one depth on the whole row) is the paper's worst case."""
    n, M = 16, 32
    z = np.full((1, n), 0.5, F32)
    filtered = fb_prefilter.prefix_filter(mi.TensorXf(z), None, M)
    z_r = np.linspace(0.35, 0.65, 301).astype(F32)
    rows, j = np.zeros(z_r.size), np.full(z_r.size, n - 1.0)
    raw = visibility(filtered, rows, j, z_r, exact_bounds=False)
    assert raw.max() > 1.05 and raw.min() < -0.05          # Gibbs ≈ ±0.09
    clamped = visibility(filtered, rows, j, z_r, clamp=True, exact_bounds=False)
    assert clamped.min() >= 0.0 and clamped.max() <= 1.0
    np.testing.assert_array_equal(clamped, np.clip(raw, 0, 1))
    # exact bounds: a single-depth row is an exact step
    exact = visibility(filtered, rows, j, z_r)
    np.testing.assert_array_equal(exact, (z_r <= 0.5).astype(F32))


def test_ringing_decays_away_from_the_step():
    n, M = 8, 32
    filtered = fb_prefilter.prefix_filter(mi.TensorXf(np.full((1, n), 0.5, F32)), None, M)
    z_r = np.array([0.2, 0.3, 0.7, 0.8], F32)
    raw = visibility(filtered, np.zeros(4), np.full(4, n - 1.0), z_r, exact_bounds=False)
    np.testing.assert_allclose(raw, [1, 1, 0, 0], atol=0.02)


# ---------------------------------------------------------------------------
# Trivial rows and z_r outside the blockers
# ---------------------------------------------------------------------------

def test_unblocked_rows_are_detected_and_exactly_lit():
    z = np.ones((4, 20), F32)
    z[1, 7] = 0.3
    z[3, :] = 0.999
    assert list(fb_basis.unblocked_rows(mi.TensorXf(z)).numpy()) == [True, False, True, False]
    assert list(fb_basis.unblocked_rows_reference(z)) == [True, False, True, False]
    filtered = fb_prefilter.prefix_filter(mi.TensorXf(z), None, 32)
    z_r = np.array([0.0, 1e-4, 0.5, 0.9999, 1.0], F32)
    for row in (0, 2):
        for j in (0.0, 3.5, 19.0):
            v = visibility(filtered, np.full(5, row), np.full(5, j), z_r)
            np.testing.assert_array_equal(v, 1.0)


def test_paper_series_wraps_around_at_depth_distance_one():
    """Plain Eq. 9 with z_r = 0 against unblocked texels gives 0.5, not 1;
    halving the depths (z ∈ [0, 1/2]) removes the wrap-around."""
    filtered = fb_prefilter.prefix_filter(mi.TensorXf(np.ones((1, 8), F32)), None, 32)
    v = visibility(filtered, [0, 0], [7.0, 7.0], [0.0, 0.5], exact_bounds=False)
    assert v[0] == pytest.approx(0.5, abs=1e-5) and v[1] == pytest.approx(1.0, abs=0.03)
    halved = fb_prefilter.prefix_filter(mi.TensorXf(np.full((1, 8), 0.5, F32)), None, 32)
    v = visibility(halved, [0], [7.0], [0.0], exact_bounds=False)
    assert v[0] == pytest.approx(1.0, abs=0.03)


@pytest.mark.parametrize("exact_bounds", [False, True])
def test_ray_in_front_of_and_behind_every_blocker(exact_bounds):
    rng = np.random.default_rng(7)
    z = rng.uniform(0.4, 0.6, (3, 32)).astype(F32)
    filtered = fb_prefilter.prefix_filter(mi.TensorXf(z), None, 64)
    rows, j = np.arange(3), np.array([31.0, 10.25, 0.0], F32)
    front = visibility(filtered, rows, j, np.full(3, 0.15), exact_bounds=exact_bounds)
    behind = visibility(filtered, rows, j, np.full(3, 0.85), exact_bounds=exact_bounds)
    if exact_bounds:
        np.testing.assert_array_equal(front, 1.0)
        np.testing.assert_array_equal(behind, 0.0)
    else:
        np.testing.assert_allclose(front, 1.0, atol=0.02)
        np.testing.assert_allclose(behind, 0.0, atol=0.02)


def test_depth_extremes_are_nan_free():
    z = np.array([[0.0, 0.0, 1.0, 1.0, 0.0, 1.0]], F32)
    rows = np.zeros(9)
    j = np.array([0, 5, 2.5, 0, 5, 2.5, -1, 9, 5], F32)
    z_r = np.array([0, 0, 0, 1, 1, 1, 0, 1, 0.5], F32)
    for regions, fit_depth in [(1, False), (2, True), (3, False)]:
        filtered = fb_prefilter.prefix_filter(mi.TensorXf(z), None, 32, regions, fit_depth)
        for clamp in (False, True):
            for exact_bounds in (False, True):
                v = visibility(filtered, rows, j, z_r, clamp=clamp, exact_bounds=exact_bounds)
                assert np.all(np.isfinite(v))
                if exact_bounds:                  # z_r = 0 is never shadowed
                    np.testing.assert_array_equal(v[z_r == 0], 1.0)


# ---------------------------------------------------------------------------
# Regions (§3.3)
# ---------------------------------------------------------------------------

def test_regions_alone_change_nothing_but_rounding():
    rng = np.random.default_rng(8)
    z = blocky_rows(rng, 4, 60)
    q = 200
    rows, j, z_r = rng.integers(0, 4, q), rng.random(q) * 59, rng.random(q)
    one = visibility(fb_prefilter.prefix_filter(mi.TensorXf(z), None, 32), rows, j, z_r, exact_bounds=False)
    three = visibility(fb_prefilter.prefix_filter(mi.TensorXf(z), None, 32, regions=3), rows, j, z_r,
                       exact_bounds=False)
    np.testing.assert_allclose(one, three, atol=2e-6)


def test_fit_depth_sharpens_narrow_depth_ranges():
    """Blockers within [0.45, 0.55]: per-region depth fitting stretches the step 5×."""
    rng = np.random.default_rng(9)
    z = rng.uniform(0.45, 0.55, (4, 48)).astype(F32)
    q = 300
    rows, j = rng.integers(0, 4, q), (rng.random(q) * 47).astype(F32)
    z_r = rng.uniform(0.45, 0.55, q).astype(F32)
    exact = np.array([fb_prefilter.average_visibility_reference(z[r], None, jj, zz)
                      for r, jj, zz in zip(rows, j, z_r)])
    errors = []
    for regions, fit_depth in [(1, False), (2, True)]:
        filtered = fb_prefilter.prefix_filter(mi.TensorXf(z), None, 32, regions, fit_depth)
        errors.append(np.abs(visibility(filtered, rows, j, z_r) - exact).mean())
    assert errors[1] < 0.5 * errors[0], errors


def test_half_storage_stays_close():
    rng = np.random.default_rng(10)
    z = blocky_rows(rng, 3, 64)
    rows, j, z_r = rng.integers(0, 3, 300), rng.random(300) * 63, rng.random(300)
    half = fb_prefilter.prefix_filter(mi.TensorXf(z), None, 32, half=True)
    assert half.B_bar.array.__class__ is mi.Float16
    full = fb_prefilter.prefix_filter(mi.TensorXf(z), None, 32)
    np.testing.assert_allclose(visibility(half, rows, j, z_r), visibility(full, rows, j, z_r),
                               atol=3e-4)


# ---------------------------------------------------------------------------
# Weights (Eqs. 11-12), references, benchmark
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("d", [1.0, 1.01, 0.98])
def test_transmittance_weights_eq11_eq12(d):
    steps = np.array([1e-5, 0.01, 0.2], F32)
    n = 50
    w = fb_basis.transmittance_weights(mi.Float(steps), n, d).numpy()
    i = np.arange(n)
    tau = steps[:, None].astype(np.float64) * (i if d == 1.0 else (d ** i - 1) / (d - 1))
    expect = np.exp(-tau) * -np.expm1(-steps[:, None] * d ** i)
    np.testing.assert_allclose(w, expect, rtol=2e-4)
    tau_end = tau[:, -1] + steps * d ** (n - 1)
    np.testing.assert_allclose(w.sum(1), -np.expm1(-tau_end), rtol=2e-4)   # W = σt ∫ T


def test_average_visibility_reference_by_hand():
    z = [0.2, 0.9, 0.9, 0.1]
    assert fb_prefilter.average_visibility_reference(z, None, 3, 0.5) == pytest.approx(0.5)
    assert fb_prefilter.average_visibility_reference(z, None, 1.5, 0.5) == pytest.approx(1.5 / 2.5)
    assert fb_prefilter.average_visibility_reference(z, [1, 3, 0, 0], 3, 0.5) == pytest.approx(0.75)
    assert fb_prefilter.average_visibility_reference(z, None, -3, 0.1) == 1.0


def test_bench_filter_runs():
    r = fb_prefilter.bench_filter(n_rows=4, n=16, M=8, pixels=64, reps=1)
    assert r["prefilter_s"] > 0 and r["evaluate_s"] > 0 and math.isfinite(r["evaluate_s"])


def test_prefix_filter_rows_bounds_and_weight_function():
    """Weights given as a function of (row, texel), known region bounds and
    a mask of the rows to filter: the filtered rows bit for bit those of
    the plain call, the others zero (a weight sum of 0: visibility 1)."""
    rng = np.random.default_rng(5)
    n_rows, n, M, regions = 6, 29, 16, 2
    z = rng.random((n_rows, n)).astype(F32)
    w = rng.random((n_rows, n)).astype(F32)
    w_flat = mi.Float(w.ravel())
    plain = fb_prefilter.prefix_filter(mi.TensorXf(z), mi.TensorXf(w), M, regions)
    bounds = fb_prefilter.region_depth_bounds(mi.TensorXf(z), regions)
    keep = np.array([True, False, True, True, False, True])
    for rows in (mi.Bool(keep), lambda r: dr.gather(mi.Bool, mi.Bool(keep), r)):
        got = fb_prefilter.prefix_filter(
            mi.TensorXf(z), lambda row, i: dr.gather(mi.Float, w_flat, row * n + i), M, regions,
            bounds=bounds, rows=rows)
        B, W = got.B_bar.numpy(), got.W.numpy()
        np.testing.assert_array_equal(B[keep], plain.B_bar.numpy()[keep])
        np.testing.assert_array_equal(W[keep], plain.W.numpy()[keep])
        assert not B[~keep].any() and not W[~keep].any()
        np.testing.assert_array_equal(got.z_lo.numpy(), plain.z_lo.numpy())
        v = visibility(got, [1, 4, 0], [10.0, 20.0, 10.0], [0.9, 0.9, 0.9])
        assert v[0] == 1.0 and v[1] == 1.0
        assert v[2] == visibility(plain, [0], [10.0], [0.9])[0]



def test_prefix_filter_layers_are_each_layers_filter():
    """Several weightings of the same rows stacked as layers (weights and
    rows functions of the stacked row): each layer bit for bit the filter
    of its weights alone, with its rows; the lookups of a stacked row read
    the common depth bounds."""
    rng = np.random.default_rng(7)
    n_rows, n, M, regions, layers = 4, 23, 16, 2, 3
    z = rng.random((n_rows, n)).astype(F32)
    w = rng.random((layers, n_rows, n)).astype(F32)
    keep = rng.random((layers, n_rows)) < 0.7
    w_flat, keep_flat = mi.Float(w.ravel()), mi.Bool(keep.ravel())
    stacked = fb_prefilter.prefix_filter(
        mi.TensorXf(z), lambda row, i: dr.gather(mi.Float, w_flat, row * n + i), M, regions,
        rows=lambda row: dr.gather(mi.Bool, keep_flat, row), layers=layers)
    assert stacked.B_bar.shape == (layers * n_rows, n, M) and stacked.layer_rows == n_rows
    B, W = stacked.B_bar.numpy(), stacked.W.numpy()
    for l in range(layers):
        one = fb_prefilter.prefix_filter(mi.TensorXf(z), mi.TensorXf(w[l]), M, regions,
                                         rows=mi.Bool(keep[l]))
        rows = slice(l * n_rows, (l + 1) * n_rows)
        np.testing.assert_array_equal(B[rows], one.B_bar.numpy())
        np.testing.assert_array_equal(W[rows], one.W.numpy())
        r = np.arange(n_rows)
        j = rng.random(n_rows) * (n - 1)
        z_r = rng.random(n_rows)
        np.testing.assert_array_equal(visibility(stacked, l * n_rows + r, j, z_r),
                                      visibility(one, r, j, z_r))
    with pytest.raises(ValueError, match="function of the stacked row"):
        fb_prefilter.prefix_filter(mi.TensorXf(z), mi.TensorXf(w[0]), M, layers=2)
