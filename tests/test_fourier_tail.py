"""The end runs of fourier_filter (integrators.fourier.tail) and the
series' near-step band (integrators.fourier.basis) against NumPy oracles."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from integrators.fourier import prefilter as fb
from integrators.fourier.tail import NO_RUN, TailVisibility, tail_run_reference, tail_runs


class _Queries:
    def __init__(self, row, beta):
        self.row, self.beta = mi.UInt32(row), mi.Float(beta)
        self.count = len(row)


class _Cover:
    def __init__(self, d, texel, frac):
        self.d, self.texel, self.frac = d, mi.UInt32(texel), mi.Float(frac)


def _rows(seed, n=6, d=40, queries=300):
    rng = np.random.default_rng(seed)
    # blocker angles with runs: steps of random length around the queries' β
    beta_b = np.repeat(rng.uniform(0.2, 0.8, (n, d // 4)), 4, axis=1)
    beta_b += rng.normal(0, 0.01, beta_b.shape) * (rng.random(beta_b.shape) < 0.3)
    row = rng.integers(0, n, queries)
    k0 = rng.integers(0, d, queries)
    beta = rng.uniform(0.2, 0.8, queries)
    frac = rng.uniform(0, 1, queries)
    return beta_b, row, k0, beta, frac


@pytest.mark.parametrize("seed", [0, 1])
def test_tail_runs_match_the_numpy_oracle(seed):
    beta_b, row, k0, beta, frac = _rows(seed)
    n, d = beta_b.shape
    q, cover = _Queries(row, beta), _Cover(d, row * d + k0, frac)
    first, k = tail_runs(q, mi.Float(beta_b.ravel().astype(np.float32)), cover, 8)
    first = np.asarray(first)
    expected = [tail_run_reference(beta_b[r].astype(np.float32), np.float32(b), int(g), 8)
                for r, b, g in zip(row, beta, k0)]
    got = [None if f == NO_RUN else int(f) for f in first]
    assert got == expected
    assert 0 < sum(e is not None for e in expected) < len(expected)   # both kinds occur
    np.testing.assert_array_equal(np.asarray(k), k0)


def test_tail_correction_replaces_the_map_on_the_runs():
    """Σ over each run of w c (V_traced − V_map), with traced values given."""
    beta_b, row, k0, beta, frac = _rows(2)
    n, d = beta_b.shape
    bb = beta_b.astype(np.float32)
    q, cover = _Queries(row, beta), _Cover(d, row * d + k0, frac)
    first, _ = tail_runs(q, mi.Float(bb.ravel()), cover, 8)
    first = np.asarray(first)
    idx = np.nonzero(first != NO_RUN)[0]
    rng = np.random.default_rng(3)
    V = (rng.random(len(idx) * 8) < 0.5).astype(np.float32)
    rank = np.zeros(len(row), np.uint32)       # each traced query's rank: its slots from 8·rank
    rank[idx] = np.arange(len(idx))
    base = rank * 8
    tail = TailVisibility(mi.UInt32(first), mi.UInt32(rank), mi.Float(V), len(idx), 8,
                          mi.UInt32(idx))
    w = rng.uniform(0.1, 2.0, n * d).astype(np.float32)
    got = np.asarray(tail.correction(q, cover, mi.Float(bb.ravel()), mi.Float(w)))
    expected = np.zeros(len(row))
    for i in idx:
        for s, g in enumerate(range(first[i], k0[i] + 1)):
            c = frac[i] if g == k0[i] else 1.0
            lit = float(np.float32(beta[i]) <= bb[row[i], g])
            expected[i] += w[row[i] * d + g] * c * (V[base[i] + s] - lit)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-5)
    # several weightings at once (layer l's at l·Q + q): each bit for bit its own
    layers = rng.uniform(0.1, 2.0, (3, n * d)).astype(np.float32)
    flat = mi.Float(layers.ravel())
    stacked = np.asarray(tail.correction(
        q, cover, mi.Float(bb.ravel()),
        lambda l, t: dr.gather(mi.Float, flat, l * (n * d) + t), layers=3))
    for l in range(3):
        one = np.asarray(tail.correction(q, cover, mi.Float(bb.ravel()), mi.Float(layers[l])))
        np.testing.assert_array_equal(stacked[l * len(row):(l + 1) * len(row)], one)


def test_band_drop_is_the_series_at_the_shifted_depths():
    """filtered_visibility(band=δ)'s drop equals the series average at z − δ
    minus the one at z + δ (NumPy oracle, no clamp, no exact bounds)."""
    rng = np.random.default_rng(4)
    rows, n, M, band = 3, 50, 32, 2.0 / 32
    z = rng.uniform(0.0, 0.5, (rows, n)).astype(np.float32)
    w = rng.uniform(0.2, 1.0, (rows, n)).astype(np.float32)
    basis = fb.prefix_filter(mi.TensorXf(z), mi.TensorXf(w), M)
    row = rng.integers(0, rows, 40)
    j = rng.uniform(0, n - 1, 40)
    z_r = rng.uniform(0.1, 0.4, 40)
    V, drop = fb.filtered_visibility(basis, mi.UInt32(row), mi.Float(j), mi.Float(z_r),
                                     clamp=False, exact_bounds=False, band=band)
    plain = fb.filtered_visibility(basis, mi.UInt32(row), mi.Float(j), mi.Float(z_r),
                                   clamp=False, exact_bounds=False)
    np.testing.assert_allclose(np.asarray(V), np.asarray(plain), atol=1e-6)
    for i in range(40):
        ref = [fb.filtered_visibility_reference(z[row[i]], w[row[i]], j[i], z_r[i] + s, M,
                                                clamp=False, exact_bounds=False)
               for s in (-band, band)]
        assert abs(float(np.asarray(drop)[i]) - (ref[0] - ref[1])) < 2e-4
