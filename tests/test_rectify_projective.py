"""Projective rectification matrix (Klehm et al. 2014, §4.2)."""
import os

import mitsuba as mi
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import integrators  # noqa: F401
from rectify import (alpha_beta_to_direction_reference, epipolar_frame, frustum_axis_angle,
                     light_coords_to_world_reference, make_slices, max_distance_to_slices,
                     projective_apply, projective_apply_reference, projective_rectification)
from rectify.projective import (auto_splits, bisectrix_alpha, projective_columns,
                                projective_row_count, projective_rows, row_ndc, share_texels)
from rectify.scenarios import light_parallel_to_image, light_toward_pixel, rotated_camera
from tests.strategies import scenario_strategy

FAR = 50.0


def frustum_points(cam, rng, n, near, far):
    """Random points inside the camera frustum between the near and far planes
    (depth along the optical axis)."""
    x = rng.uniform(0, cam.width, n)
    y = rng.uniform(0, cam.height, n)
    z = rng.uniform(near, far, n)
    return cam.origin + z[:, None] * cam.direction(x, y)


def test_refuses_on_screen_epipole():
    cam = rotated_camera(width=32, height=24)
    for light in (light_toward_pixel(cam, 10, 10), light_toward_pixel(cam, 10, 10, behind=True),
                  light_toward_pixel(cam, 3, 3, "point")):
        rect, reason = projective_rectification(epipolar_frame(cam, light), FAR)
        assert rect is None and "on screen" in reason
    # just off screen: too close (view rays nearly parallel to the light)
    fr = epipolar_frame(cam, light_toward_pixel(cam, -0.5, 12))
    rect, reason = projective_rectification(fr, FAR)
    assert rect is None and "too close" in reason
    rect, _ = projective_rectification(fr, FAR, min_angle_deg=0.0)
    assert rect is not None
    assert projective_rectification(fr, -1.0)[0] is None


def test_available_far_off_and_at_infinity():
    cam = rotated_camera(width=32, height=24)
    for light in (light_toward_pixel(cam, -200, 12), light_parallel_to_image(cam, 30.0),
                  light_toward_pixel(cam, 500, -300, "point", distance=5.0)):
        fr = epipolar_frame(cam, light)
        rect, reason = projective_rectification(fr, FAR)
        assert rect is not None, reason
        assert np.all(np.isfinite(rect.matrix)) and rect.min_angle_deg == frustum_axis_angle(fr)


@settings(max_examples=int(os.environ.get("RECTIFY_EXAMPLES", 100)), deadline=None)
@given(scenario_strategy(), st.integers(0, 2**31 - 1))
def test_projective_properties(sc, seed):
    cam, light, label = sc
    fr = epipolar_frame(cam, light)
    near = cam.near_clip
    rect, reason = projective_rectification(fr, FAR, near=near)
    if fr.in_image:
        assert rect is None
    assume(rect is not None)
    rng = np.random.default_rng(seed)
    # the frustum fills [-1, 1]^3
    p = frustum_points(cam, rng, 300, near, FAR)
    q = projective_apply_reference(rect, p)
    assert np.all(np.abs(q) <= 1 + 1e-9), label
    corners = np.array([cam.origin + z * cam.direction(x, y) for z in (near, FAR)
                        for x in (0, cam.width) for y in (0, cam.height)])
    qc = projective_apply_reference(rect, corners)
    for axis in range(3):
        assert qc[:, axis].min() == pytest.approx(-1, abs=1e-9)
        assert qc[:, axis].max() == pytest.approx(1, abs=1e-9)
    # fast == reference
    P = mi.Point3f(*(mi.Float(p[:, i]) for i in range(3)))
    qf = projective_apply(rect, P)
    qf = np.stack([np.asarray(qf.x), np.asarray(qf.y), np.asarray(qf.z)], axis=1)
    np.testing.assert_allclose(qf, q, atol=1e-3)
    # points of one epipolar half-plane share one row
    alpha = rng.uniform(-np.pi, np.pi)
    beta = rng.uniform(0.05, np.pi - 0.05, 50)
    t = rng.uniform(1.0, FAR, 50)
    pts = cam.origin + t[:, None] * alpha_beta_to_direction_reference(fr, np.full(50, alpha), beta)
    rows = projective_apply_reference(rect, pts)[:, 1]
    np.testing.assert_allclose(rows, rows[0], atol=1e-9)
    # along a view ray: column increases with distance, depth is constant
    d = cam.direction(rng.uniform(0, cam.width), rng.uniform(0, cam.height))
    ts = np.sort(rng.uniform(near, FAR, 20))
    qr = projective_apply_reference(rect, cam.origin + ts[:, None] * d)
    assert np.all(np.diff(qr[:, 0]) > 0), label
    np.testing.assert_allclose(qr[:, 2], qr[0, 2], atol=1e-9)
    np.testing.assert_allclose(qr[:, 1], qr[0, 1], atol=1e-9)
    # along a light ray: one texel, depth grows away from the light
    x0 = p[0]
    if fr.is_directional:
        s = np.linspace(-5, 5, 11)
        lp = x0[None] - s[:, None] * fr.axis          # s grows away from the light
    else:
        w = x0 - fr.light_position
        s = np.linspace(0.5, 1.5, 11)
        lp = fr.light_position + s[:, None] * w
    ql = projective_apply_reference(rect, lp)
    np.testing.assert_allclose(ql[:, :2], np.broadcast_to(ql[:1, :2], ql[:, :2].shape), atol=1e-8)
    assert np.all(np.diff(ql[:, 2]) > 0), label


# --------------------------------------------------------------------------
# Rows and columns of the projectively rectified map (directional light)
# --------------------------------------------------------------------------

OFF_SCREEN = [  # (camera kwargs, film point of the epipole, behind)
    (dict(width=64, height=48), (-64.0, 14.0), False),
    (dict(width=64, height=48, yaw_deg=20, roll_deg=30), (200.0, -90.0), True),
    (dict(width=48, height=48, pitch_deg=-10), (24.0, -300.0), False),
]


def off_screen_frame(cam_kw, px, behind):
    cam = rotated_camera(**cam_kw)
    return epipolar_frame(cam, light_toward_pixel(cam, *px, behind=behind))


@pytest.mark.parametrize("cam_kw,px,behind", OFF_SCREEN)
def test_projective_rows_are_slices_equally_spaced_in_ndc(cam_kw, px, behind):
    """Row k is the slice α_k with r = tan(α_k − α_mid) equally spaced, its
    NDC row (by the matrix, NumPy oracle) equally spaced over [-1, 1];
    every pixel centre lies within half a pixel of a row (the automatic
    count), and the count is not far above Baran's sinh slices at this
    distance of the epipole."""
    fr = off_screen_frame(cam_kw, px, behind)
    rect, reason = projective_rectification(fr, FAR)
    assert rect is not None, reason
    rows = projective_rows(fr, rect)
    assert rows.count == projective_row_count(fr, rect)
    np.testing.assert_allclose(rows.ndc, np.linspace(-1, 1, rows.count), atol=1e-9)
    np.testing.assert_allclose(np.tan(rows.slices.alpha - bisectrix_alpha(fr, rect)), rows.r,
                               rtol=1e-9, atol=1e-12)
    # the matrix maps any point of slice α_k to NDC row ndc[k]
    rng = np.random.default_rng(3)
    for k in rng.choice(rows.count, 5, replace=False):
        beta = rng.uniform(0.3, np.pi - 0.3, 8)
        p = fr.camera.origin + rng.uniform(1, FAR, 8)[:, None] * \
            alpha_beta_to_direction_reference(fr, np.full(8, rows.slices.alpha[k]), beta)
        np.testing.assert_allclose(projective_apply_reference(rect, p)[:, 1], rows.ndc[k],
                                   atol=1e-9)
    # end points on the image border
    P = rows.slices.points
    W, H = fr.width, fr.height
    on_border = (np.isclose(P[:, 0], 0) | np.isclose(P[:, 0], W) | np.isclose(P[:, 1], 0)
                 | np.isclose(P[:, 1], H))
    assert on_border.all()
    assert max_distance_to_slices(fr, rows.slices) <= 0.5 + 1e-3
    np.testing.assert_allclose(row_ndc(rect, rows.r), rows.ndc, atol=1e-12)


def test_projective_row_count_grows_as_the_epipole_nears_the_screen():
    """Equal steps in tan need more rows than Baran's sinh slices when the
    lines fan out (measured at 320×240: 7.0× at 2.4° from the light
    direction, 1.9× at 12.6°, 1.2× at 30°, 1.08× at 41°, 1.03× at 49°)."""
    cam = rotated_camera(width=320, height=240)
    ratios = []
    for x in (-5000.0, -320.0, -60.0, -5.0):
        fr = epipolar_frame(cam, light_toward_pixel(cam, x, 100.0))
        rect, _ = projective_rectification(fr, FAR, min_angle_deg=0.0)
        ratios.append(projective_row_count(fr, rect) / make_slices(fr, "sinh").count)
    assert ratios[0] < 1.1 and all(np.diff(ratios) > 0) and ratios[-1] > 10, ratios


def test_projective_columns_are_equal_steps_in_the_matrix_column():
    """Texel edges: equal steps of the matrix's column coordinate A_c/x + B_c
    within every split (each split one projective map), splits geometric;
    the light ray through a texel centre maps to one (column, row) texel
    all along (NumPy oracle: the matrix)."""
    fr = off_screen_frame(*OFF_SCREEN[0])
    rect, _ = projective_rectification(fr, FAR)
    rows = projective_rows(fr, rect)
    cols = projective_columns(0.01, 40.0, 200, splits=auto_splits(0.01, 40.0))
    assert len(cols.split_x) - 1 == 12 and cols.d == 200 and cols.texels.sum() == 200
    np.testing.assert_allclose(cols.split_x[1:] / cols.split_x[:-1], 4000 ** (1 / 12))
    assert np.all(np.diff(cols.edges) > 0)
    start = 0
    for m in cols.texels:
        inv = 1.0 / cols.edges[start:start + m + 1]
        np.testing.assert_allclose(np.diff(inv), np.diff(inv)[0], rtol=1e-9)
        centres = 1.0 / cols.centres[start:start + m]
        np.testing.assert_allclose(centres, 0.5 * (inv[:-1] + inv[1:]), rtol=1e-12)
        start += m
    # a light ray through a texel centre of row k: constant (column, row)
    k = rows.count // 3
    gamma = cols.centres * rows.inv_cos[k]
    for u in (-5.0, 0.0, 7.0):
        q = projective_apply_reference(rect, light_coords_to_world_reference(
            fr, np.full(cols.d, rows.slices.alpha[k]), gamma, np.full(cols.d, u)))
        np.testing.assert_allclose(q[:, 1], rows.ndc[k], atol=1e-8)
        if u == -5.0:
            col0 = q[:, 0]
        np.testing.assert_allclose(q[:, 0], col0, rtol=1e-9, atol=1e-9)
    assert np.all(np.diff(col0) > 0)
    # the matrix's column is affine in 1/x: the edges of a split are equal steps in NDC
    q = projective_apply_reference(rect, light_coords_to_world_reference(
        fr, np.full(cols.d + 1, rows.slices.alpha[k]), cols.edges * rows.inv_cos[k],
        np.zeros(cols.d + 1)))
    start = 0
    for m in cols.texels:
        step = np.diff(q[start:start + m + 1, 0])
        np.testing.assert_allclose(step, step[0], rtol=1e-6)
        start += m


def test_share_texels_and_splits():
    assert share_texels([1, 1, 1], 10).tolist() == [4, 3, 3]
    assert share_texels([1, 4, 16], 21).tolist() == [1, 4, 16]
    assert share_texels([0.0, 1.0], 5).tolist() == [1, 4]
    with pytest.raises(ValueError):
        share_texels([1, 1, 1], 2)
    assert auto_splits(1.0, 2.0) == 1 and auto_splits(1.0, 2.01) == 2 and auto_splits(1, 1) == 1
    with pytest.raises(ValueError):
        projective_columns(0.0, 1.0, 10)
