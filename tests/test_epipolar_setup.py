"""Rectified maps of integrators.epipolar_setup against per-sample NumPy oracles."""
import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from integrators import epipolar_setup as es
from integrators.capture import capture_camera
from integrators.partial_sum_tree import BlockerModes
from integrators.scene_params import SceneParams
from rectify import direction_to_alpha_beta_reference, pixel_to_slice_reference
from tests.conftest import scene_dict

RES = (32, 24)
SPHERE_C, SPHERE_R = np.array([0.0, 0.8, 0.0]), 0.4   # conftest's blocker
FLOOR_Y, FLOOR_HALF = -1.0, 3.0                        # conftest's floor


def setup(light=None, ring_deg=2.0, slices=0, **kw):
    scene = mi.load_dict(scene_dict(res=RES, **({"light": light} if light else {}), **kw))
    params = SceneParams.from_scene(scene)
    cap = capture_camera(params, surface=False)
    frame = es.epipolar_frame_of(params)
    sl = es.choose_slices(frame, slices)
    return params, cap, frame, sl, es.assign_queries(params, frame, sl, cap, ring_deg)


def on_screen_light():
    """A light in front of the camera (epipole inside the image)."""
    return {"type": "directional", "direction": [0.05, -0.1, 1.0], "irradiance": 2.0}


@pytest.mark.parametrize("light", [None, "on_screen"])
def test_queries_against_per_sample_numpy(light):
    """Every non-ring sample with d > 0 is a query of its nearest slice, at
    its own β and γ_end = t_end sin β, sorted by β within its row."""
    params, cap, frame, sl, q = setup(on_screen_light() if light else None, ring_deg=3.0)
    W, H = RES
    yy, xx = np.mgrid[0:H, 0:W]
    x, y = xx.ravel() + 0.5, yy.ravel() + 0.5
    _, beta = direction_to_alpha_beta_reference(frame, frame.camera.direction(x, y))
    _, _, k0, k1, f = pixel_to_slice_reference(frame, sl, x, y)
    nearest = np.where(f < 0.5, k0, k1)
    d = np.array(cap.d)
    ring = np.minimum(beta, np.pi - beta) < math.radians(3.0)
    expected = np.flatnonzero((d > 0) & ~ring)
    assert (light is None) == (not ring.any())

    sample, row, col = np.array(q.sample), np.array(q.row), np.array(q.col)
    assert sorted(sample.tolist()) == expected.tolist()
    assert sorted(np.array(q.ring_sample).tolist()) == np.flatnonzero(ring & (d > 0)).tolist()
    slice_of_query = np.array(q.slice_index)[row]
    clear = np.abs(f[sample] - 0.5) > 1e-3            # not a tie between two slices
    assert np.all(slice_of_query[clear] == nearest[sample][clear])
    qbeta = np.array(q.beta)
    np.testing.assert_allclose(qbeta, beta[sample], atol=2e-6)
    t_near = params.camera.near_clip / (frame.camera.direction(x, y)[sample]
                                        / np.linalg.norm(frame.camera.direction(x, y)[sample],
                                                         axis=1, keepdims=True)
                                        @ params.camera.forward)
    np.testing.assert_allclose(np.array(q.t_near), t_near, rtol=1e-4)
    np.testing.assert_allclose(np.array(q.gamma_end), (t_near + d[sample]) * np.sin(beta[sample]),
                               rtol=1e-5, atol=1e-6)
    # sweep order: rows contiguous, col = rank by β inside the row
    counts = np.array(q.r_count)
    assert q.r == counts.max() and counts.sum() == len(sample)
    assert np.all(np.diff(row) >= 0)
    for s in range(q.n):
        sel = row == s
        assert np.array_equal(col[sel], np.arange(counts[s]))
        assert np.all(np.diff(qbeta[sel]) >= 0)

    # depth D = γ_end / Δγ, Δγ = (max γ_end of the row) / d
    rays = es.light_ray_grid(params, q, 40)
    D = np.array(es.rectified_depth(q, rays))
    gmax = np.zeros(q.n)
    np.maximum.at(gmax, row, np.array(q.gamma_end))
    np.testing.assert_allclose(D[row, col], np.array(q.gamma_end) / (gmax[row] / 40), rtol=1e-5)
    assert np.all(D.max(axis=1) <= 40 + 1e-3)


def first_blocker_u(base, w):
    """NumPy oracle: largest u where the line base + u w meets the sphere or
    the floor rectangle (the first blocker coming from the light), or None."""
    hits = []
    oc = base - SPHERE_C
    b, c = oc @ w, oc @ oc - SPHERE_R ** 2
    disc = b * b - c
    if disc >= 0:
        hits.append(-b + math.sqrt(disc))
    if abs(w[1]) > 1e-12:
        u = (FLOOR_Y - base[1]) / w[1]
        p = base + u * w
        if abs(p[0]) <= FLOOR_HALF and abs(p[2]) <= FLOOR_HALF:
            hits.append(u)
    return max(hits) if hits else None


@pytest.mark.parametrize("light", [None, "on_screen"])
def test_traced_blocker_map_against_ray_oracle(light):
    params, cap, frame, sl, q = setup(on_screen_light() if light else None)
    rays = es.light_ray_grid(params, q, 24)
    beta_b = np.array(es.trace_blocker_angles(params, q, rays, k=1)).reshape(q.n, 24)
    alpha = np.array(q.alpha, np.float64)
    dg = np.array(rays.delta_gamma, np.float64)
    o, w = params.camera.origin, frame.axis
    expected = np.full((q.n, 24), np.pi)
    for s in range(q.n):
        perp = math.cos(alpha[s]) * frame.b1 + math.sin(alpha[s]) * frame.b2
        for g in range(24):
            gamma = (g + 0.5) * dg[s]
            u_b = first_blocker_u(o + gamma * perp, w)
            if u_b is not None:
                expected[s, g] = math.atan2(gamma, u_b)
    blocked = expected < np.pi
    assert blocked.any() and (~blocked).any()
    # the sphere is tessellation-free in Mitsuba; allow silhouettes/edges to flip
    agree = (beta_b < np.pi) == blocked
    assert agree.mean() > 0.99, agree.mean()
    both = agree & blocked
    np.testing.assert_allclose(beta_b[both], expected[both], atol=2e-4)


def test_blocker_modes_are_row_searchsorted():
    """Blocker β -> view-ray index = number of the row's queries with β_q ≤ β_b."""
    params, cap, frame, sl, q = setup(on_screen_light())
    k = 3
    rays = es.light_ray_grid(params, q, 16)
    beta_b = es.trace_blocker_angles(params, q, rays, k=k)
    modes = es.blocker_modes(q, rays, beta_b, k)
    bb = np.array(beta_b).reshape(q.n, 16, k)
    row, qbeta = np.array(q.row), np.array(q.beta)
    idx = np.empty_like(bb)
    for s in range(q.n):
        idx[s] = np.searchsorted(qbeta[row == s], bb[s], side="right")
    b, w = np.array(modes.beta), np.array(modes.weight)
    # merged modes: for every index value, the weights add up to count/k
    for s in range(q.n):
        for g in range(16):
            vals, counts = np.unique(idx[s, g], return_counts=True)
            got = {v: w[s, g][b[s, g] == v].sum() for v in vals}
            for v, c in zip(vals, counts):
                assert got[v] == pytest.approx(c / k)
            assert w[s, g].sum() == pytest.approx(1.0)


def test_merge_modes():
    index = mi.UInt32([5, 5, 7, 5, 9, 9, 9, 9])          # two light rays, k = 4
    b, w = es.merge_modes(index, 4)
    np.testing.assert_allclose(np.array(w), [0.75, 0, 0.25, 0, 1, 0, 0, 0])
    np.testing.assert_allclose(np.array(b)[[0, 2, 4]], [5, 7, 9])


def test_light_side_factor_against_slab_oracle():
    params, cap, frame, sl, q = setup(sigma_t={"type": "rgb", "value": [0.1, 0.3, 0.9]})
    rays = es.light_ray_grid(params, q, 8)
    L = np.array(es.light_side_factor(params, q, rays))
    assert L.shape == (q.n, 8, 3)
    alpha, dg = np.array(q.alpha, np.float64), np.array(rays.delta_gamma, np.float64)
    h_ref = np.array(rays.h_ref, np.float64)
    med = params.medium
    for s in range(0, q.n, 7):
        perp = math.cos(alpha[s]) * frame.b1 + math.sin(alpha[s]) * frame.b2
        for g in range(8):
            base = params.camera.origin + (g + 0.5) * dg[s] * perp
            with np.errstate(divide="ignore"):
                t0, t1 = (med.bounds_min - base) / frame.axis, (med.bounds_max - base) / frame.axis
            h = np.min(np.maximum(t0, t1))
            np.testing.assert_allclose(L[s, g], np.exp(-med.sigma_t * (h - h_ref[s])), rtol=1e-4)
    assert np.all(L <= 1.0)


def test_grey_sigma_t_gives_one_channel():
    params, cap, frame, sl, q = setup()
    rays = es.light_ray_grid(params, q, 8)
    assert tuple(es.light_side_factor(params, q, rays).shape) == (q.n, 8)


def test_first_leaf_visibility():
    modes = BlockerModes(mi.TensorXf(np.array([[[0, 3], [0, 0]], [[2, 9], [0, 0]]], np.float32)),
                         mi.TensorXf(np.array([[[0.5, 0.5], [1, 0]], [[1, 0], [1, 0]]],
                                              np.float32)))
    q = es.EpipolarQueries(None, None, 2, 4, None, None, None, None,
                           mi.UInt32([0, 0, 1, 1]), mi.UInt32([0, 3, 1, 2]),
                           None, None, None, None, 4)
    np.testing.assert_allclose(np.array(es.first_leaf_visibility(q, modes)), [0.5, 0, 1, 0])


def test_ring_and_zero_depth_samples_are_no_queries():
    params, cap, frame, sl, q = setup(on_screen_light(), ring_deg=10.0)
    assert dr.width(q.ring_sample) > 0
    betas = np.array(q.beta)
    assert np.all(np.minimum(betas, np.pi - betas) >= math.radians(10.0) - 1e-6)


def test_only_directional_lights():
    for light in ("point", "spot"):
        scene = mi.load_dict(scene_dict(light=light, res=(8, 6)))
        with pytest.raises(ValueError, match="only directional lights"):
            es.require_directional(SceneParams.from_scene(scene), "epipolar_tree")
