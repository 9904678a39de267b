"""Projective rectification matrix (Klehm et al. 2014, §4.2)."""
import os

import mitsuba as mi
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import integrators  # noqa: F401
from rectify import (alpha_beta_to_direction_reference, epipolar_frame, frustum_axis_angle,
                     projective_apply, projective_apply_reference, projective_rectification)
from rectify.scenarios import (light_parallel_to_image, light_toward_pixel, rotated_camera,
                               scenario_strategy)

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
