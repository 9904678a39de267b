"""The reference rays of a frame made together (``fourier_filter``):
their kernels in one array and their class sums in few prefix sums, each
bit for bit what one ray at a time gives, and against NumPy."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from test_fourier_defaults import _exact_inputs

from integrators.fourier import rectified_map as rm
from integrators.fourier.references import reference_rays, row_kernel


def _random_map(rng, n=7, d=13, Q=40):
    series = rng.random(n * d) < 0.5
    lit = ~series & (rng.random(n * d) < 0.5)
    filtered = series.reshape(n, d).any(1)
    z = rng.random(n * d).astype(np.float32)
    smap = rm.RectifiedShadowMap(
        n, d, mi.Float(z), mi.Bool(series), mi.Bool(lit), mi.Float(rng.random(Q)),
        mi.Bool(filtered), mi.UInt32(np.flatnonzero(filtered).astype(np.uint32)),
        mi.UInt32((np.cumsum(filtered) - filtered).astype(np.uint32)))
    row = rng.integers(0, n, Q)
    D = rng.random(Q) * d
    k0 = np.minimum(D.astype(int), d - 1)
    cover = rm.Coverage(d, mi.UInt32((row * d + k0).astype(np.uint32)),
                        mi.Float((D - k0).astype(np.float32)), mi.Float(D - 1.0))
    return smap, cover, (series, lit, row, k0, D - k0)


def _class_sums_numpy(w, series, lit, row, k0, frac, d):
    out = np.zeros((3, len(row)))
    for q in range(len(row)):
        c = np.zeros(d)
        c[:k0[q]] = 1.0
        c[k0[q]] = frac[q]
        g = slice(row[q] * d, row[q] * d + d)
        ww = w[g].astype(np.float64) * c
        out[:, q] = (ww * lit[g]).sum(), (ww * series[g]).sum(), ww.sum()
    return out


@pytest.mark.parametrize("limit_rays", [1, 2, 5])
def test_stacked_class_sums_are_each_rays_sums(monkeypatch, limit_rays):
    rng = np.random.default_rng(3)
    smap, cover, (series, lit, row, k0, frac) = _random_map(rng)
    size, count = dr.width(smap.lit), 5
    monkeypatch.setattr(rm, "STACK_LIMIT", 3 * size * limit_rays)
    L = rng.random(size).astype(np.float32)
    K = rng.random(count * size).astype(np.float32)
    table = rm.stacked_class_sums(smap, cover, mi.Float(L), mi.Float(K), count)
    assert len(table.batches) == -(-count // limit_rays)
    lane_k = rng.integers(0, count, len(row)).astype(np.uint32)
    per_lane = [np.asarray(x) for x in table.at(mi.UInt32(lane_k))]
    for k in range(count):
        got = table.of(k)
        w = rm.kernel_weights(mi.Float(L), mi.Float(K), size)
        one = rm.class_and_total_sums(smap, cover, lambda t: w(k, t))
        for c, (a, b) in enumerate(zip(got, one)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
            np.testing.assert_array_equal(per_lane[c][lane_k == k], np.asarray(a)[lane_k == k])
        oracle = _class_sums_numpy(L * K[k * size:(k + 1) * size], series, lit, row, k0, frac,
                                   smap.d)
        np.testing.assert_allclose(np.array([np.asarray(x) for x in got]), oracle,
                                   rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("name", ["sun_room", "point_fog"])
def test_stacked_row_kernels_are_each_rays_kernel(name):
    inp = _exact_inputs(name)
    q, rays, sigma_t = inp["queries"], inp["rays"], inp["sigma_t"]
    refs = reference_rays(q, sigma_t, 10.0, count=3)
    n = dr.width(refs.counts)
    K = np.asarray(row_kernel(inp["params"], q, rays, sigma_t, refs.beta, refs.count))
    beta = np.asarray(refs.beta)
    size = len(K) // 3
    for k in range(3):
        one = row_kernel(inp["params"], q, rays, sigma_t, mi.Float(beta[k * n:(k + 1) * n]))
        np.testing.assert_array_equal(K[k * size:(k + 1) * size], np.asarray(one))
    assert np.isfinite(K).all() and (K > 0).any()


@pytest.mark.parametrize("name", ["spot_room", "point_fog"])
def test_layer_batches_change_nothing(monkeypatch, name):
    """The reference rays' filters in batches of one layer (textures over
    the memory limit) or all at once: the same image, bit for bit."""
    from experiments import common as c
    from integrators.fourier import layers

    scene = c.load(c.scene_file(name), c.resolution(40, 30))
    integ = mi.load_dict({"type": "fourier_filter", "reference_rays": 3})
    whole = np.asarray(mi.render(scene, integrator=integ, spp=1))
    monkeypatch.setattr(layers, "FILTER_BYTES", 1)
    assert np.array_equal(np.asarray(mi.render(scene, integrator=integ, spp=1)), whole)
