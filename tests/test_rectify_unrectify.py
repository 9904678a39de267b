"""Rectified grid and unrectification (bilinear and depth-aware)."""
import os

import mitsuba as mi
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import integrators  # noqa: F401
from rectify import (epipolar_frame, grid_directions, grid_directions_reference,
                     per_slice_beta_grid, ring_mask_reference, shared_beta_grid, sinh_slices,
                     uniform_slices, unrectify, unrectify_bilateral, unrectify_bilateral_reference,
                     unrectify_reference)
from rectify.scenarios import light_toward_pixel, rotated_camera
from tests.strategies import scenario_strategy

#: RECTIFY_EXAMPLES=2000 for a long stress run
SETTINGS = settings(max_examples=int(os.environ.get("RECTIFY_EXAMPLES", 40)), deadline=None)


def smooth(d):
    """A smooth positive function of the view direction (its curvature keeps
    bilinear interpolation within 1% even at 16 px across a 110 deg view)."""
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    return 1.0 + 0.3 * np.sin(1.5 * d[..., 0] + 1) * np.cos(2 * d[..., 1]) + 0.2 * d[..., 2]


def pixel_dirs(cam):
    yy, xx = np.mgrid[0:cam.height, 0:cam.width]
    return cam.direction(xx + 0.5, yy + 0.5)


def make(sc, grid_kind, slice_kind="sinh"):
    cam, light, label = sc
    fr = epipolar_frame(cam, light)
    s = sinh_slices(fr) if slice_kind == "sinh" else uniform_slices(fr)
    g = shared_beta_grid(fr, s) if grid_kind == "shared" else per_slice_beta_grid(fr, s)
    return cam, fr, s, g, label


@SETTINGS
@given(scenario_strategy(max_width=32, max_height=24), st.sampled_from(["shared", "per_slice"]),
       st.integers(0, 2**31 - 1))
def test_unrectify_matches_reference(sc, grid_kind, seed):
    cam, fr, s, g, label = make(sc, grid_kind)
    rng = np.random.default_rng(seed)
    vals = rng.uniform(-1, 2, size=(s.count, g.count))
    img = np.asarray(unrectify(fr, s, g, vals))
    ref = unrectify_reference(fr, s, g, vals)
    assert img.shape == (cam.height, cam.width) and np.all(np.isfinite(img))
    # float32 alpha/beta: taps move by ~1e-4 of a sample; values differ by <= 3.
    # At the (anti-)epipole alpha is undefined (every slice meets there); just
    # outside the ring it turns fastest (the epipole on a corner pixel, 28x12:
    # one pixel 2.007e-3 off), hence the tolerance.
    defined = ~ring_mask_reference(fr, 0.05)
    np.testing.assert_allclose(img[defined], ref[defined], atol=3e-3, err_msg=label)
    vals3 = rng.uniform(0, 1, size=(s.count, g.count, 3))
    img3 = np.asarray(unrectify(fr, s, g, mi.TensorXf(vals3.astype(np.float32))))
    assert img3.shape == (cam.height, cam.width, 3)
    np.testing.assert_allclose(img3[defined], unrectify_reference(fr, s, g, vals3)[defined],
                               atol=2e-3, err_msg=label)


@SETTINGS
@given(scenario_strategy(max_width=40, max_height=30), st.sampled_from(["shared", "per_slice"]),
       st.sampled_from(["sinh", "uniform"]))
def test_unrectify_of_rectified_smooth_image(sc, grid_kind, slice_kind):
    """unrectify(rectify(f)) reproduces a smooth image within 1% outside the ring."""
    cam, fr, s, g, label = make(sc, grid_kind, slice_kind)
    vals = smooth(grid_directions_reference(fr, s, g))
    img = np.asarray(unrectify(fr, s, g, vals))
    truth = smooth(pixel_dirs(cam))
    ring = ring_mask_reference(fr)
    err = np.abs(img - truth) / truth
    assert np.all(np.isfinite(img))
    assert err[~ring].max() <= 0.01, (label, err[~ring].max())


@SETTINGS
@given(scenario_strategy(max_width=24, max_height=18))
def test_grid_directions_match_reference(sc):
    cam, fr, s, g, label = make(sc, "per_slice")
    d = grid_directions(fr, s, g)
    fast = np.stack([np.asarray(d.x), np.asarray(d.y), np.asarray(d.z)], axis=1)
    ref = grid_directions_reference(fr, s, g).reshape(-1, 3)
    np.testing.assert_allclose(fast, ref, atol=2e-6)
    np.testing.assert_allclose(np.linalg.norm(ref, axis=1), 1.0, atol=1e-12)


def two_layer_scene(cam):
    """Depth 1 left of a slanted image line, 10 right of it (as functions of the
    view direction), and radiance that differs strongly between the layers."""
    def depth(d):
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        return np.where(d @ cam.x_axis + 0.3 * (d @ cam.y_axis) > 0.05, 1.0, 10.0)

    def radiance(d):
        return smooth(d) * np.where(depth(d) < 5, 0.2, 2.0)
    return depth, radiance


@pytest.mark.parametrize("epipole", [(20.0, 15.0), (-30.0, 10.0)])
def test_bilateral_keeps_depth_edges(epipole):
    cam = rotated_camera((0, 1, 0), 10, 5, 0, 60, 40, 30)
    fr = epipolar_frame(cam, light_toward_pixel(cam, *epipole))
    s = sinh_slices(fr)
    g = per_slice_beta_grid(fr, s)
    depth, radiance = two_layer_scene(cam)
    dirs = grid_directions_reference(fr, s, g)
    vals, sdepth = radiance(dirs), depth(dirs)
    pd = depth(pixel_dirs(cam))
    truth = radiance(pixel_dirs(cam))
    plain = np.asarray(unrectify(fr, s, g, vals))
    bil, wsum = unrectify_bilateral(fr, s, g, vals, sdepth, pd, depth_sigma=0.1)
    bil, wsum = np.asarray(bil), np.asarray(wsum)
    ref, wref = unrectify_bilateral_reference(fr, s, g, vals, sdepth, pd, depth_sigma=0.1)
    ring = ring_mask_reference(fr)
    ok = ~ring & (wref > 1e-3) & (np.abs(wsum - wref) < 1e-3)
    np.testing.assert_allclose(bil[ok], ref[ok], atol=2e-3)
    np.testing.assert_allclose(wsum, wref, atol=5e-3)
    e_plain = np.abs(plain - truth)[~ring]
    e_bil = np.abs(bil - truth)[~ring & (wsum > 1e-3)]
    assert e_plain.max() > 0.3                  # bilinear smears the edge
    assert e_bil.max() < 0.05 * truth.max()     # bilateral does not
    # pixels without a same-depth sample are reported (tiny weight sum)
    assert np.all(np.isfinite(bil)) and np.all(wsum >= 0)


def test_bilateral_with_equal_depths_is_bilinear():
    cam = rotated_camera((0, 0, 0), 0, 0, 0, 60, 24, 18)
    fr = epipolar_frame(cam, light_toward_pixel(cam, 5.5, 4.5, "point", distance=4.0))
    s = sinh_slices(fr)
    g = shared_beta_grid(fr, s)
    rng = np.random.default_rng(1)
    vals = rng.uniform(size=(s.count, g.count, 2))
    bil, wsum = unrectify_bilateral(fr, s, g, vals, np.full((s.count, g.count), 3.0),
                                    np.full((18, 24), 3.0))
    np.testing.assert_allclose(np.asarray(bil), np.asarray(unrectify(fr, s, g, vals)), atol=1e-5)
    np.testing.assert_allclose(np.asarray(wsum), 1.0, atol=1e-5)


def test_shape_errors():
    cam = rotated_camera(width=16, height=12)
    fr = epipolar_frame(cam, light_toward_pixel(cam, 8, 6))
    s = sinh_slices(fr)
    g = shared_beta_grid(fr, s)
    with pytest.raises(ValueError):
        unrectify(fr, s, g, np.zeros((s.count + 1, g.count)))
    with pytest.raises(ValueError):
        unrectify_bilateral(fr, s, g, np.zeros((s.count, g.count)), np.zeros((s.count, g.count)),
                            np.zeros((11, 16)))
