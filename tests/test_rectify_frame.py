"""Epipolar frame, rectified coordinates, ring and describe()."""
import math
import os

import mitsuba as mi
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import integrators  # noqa: F401  (sets the variant)
from rectify import (describe, direction_to_alpha_beta_reference, epipolar_frame,
                     light_coords_to_world, light_coords_to_world_reference, light_to_view,
                     light_to_view_reference, pixel_to_alpha_beta, pixel_to_alpha_beta_reference,
                     alpha_beta_to_pixel, ray_meeting_t, ray_meeting_t_reference, ring_mask,
                     ring_mask_reference, view_coords_to_world, view_coords_to_world_reference,
                     view_to_light, view_to_light_reference, world_to_light_coords,
                     world_to_light_coords_reference, world_to_view_coords,
                     world_to_view_coords_reference)
from rectify._dr import pixel_centres
from rectify.scenarios import (light_parallel_to_image, light_toward_pixel, nasty_epipoles,
                               rotated_camera)
from tests.strategies import scenario_strategy

#: RECTIFY_EXAMPLES=2000 for a long stress run
SETTINGS = settings(max_examples=int(os.environ.get("RECTIFY_EXAMPLES", 100)), deadline=None)


def finite_frame(fr):
    for v in (fr.axis, fr.b1, fr.b2, fr.epipole, fr.epipole_h, fr.direction):
        assert np.all(np.isfinite(v))
    basis = np.stack([fr.b1, fr.b2, fr.axis])
    np.testing.assert_allclose(basis @ basis.T, np.eye(3), atol=1e-12)
    assert fr.epipole_h[2] >= 0


def points_around(frame, rng, n=200):
    """World points at random directions/distances from the eye, plus some on
    the camera-light axis and near the light."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = np.exp(rng.uniform(np.log(0.01), np.log(100.0), size=n))
    p = frame.camera.origin + t[:, None] * d
    p[:3] = frame.camera.origin + np.array([0.5, 2.0, 7.0])[:, None] * frame.axis
    return p


def p3(a):
    return mi.Point3f(*(mi.Float(a[:, i].astype(np.float32)) for i in range(3)))


def np3(v):
    return np.stack([np.asarray(v.x), np.asarray(v.y), np.asarray(v.z)], axis=1)


# -- frame ------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["directional", "point", "spot"])
def test_frame_cases(kind):
    cam = rotated_camera((1, 2, 3), 30, 10, 20, 60, 32, 24)
    e = nasty_epipoles(32, 24)
    cases = {"centre": "on_screen", "pixel_centre": "on_screen", "near_corner": "on_screen",
             "off_left": "off_screen", "off_top": "off_screen", "far_off": "off_screen",
             "very_far_off": "off_screen"}
    for name, case in cases.items():
        fr = epipolar_frame(cam, light_toward_pixel(cam, *e[name], kind=kind))
        assert fr.case == case, name
        np.testing.assert_allclose(fr.epipole, e[name], rtol=1e-6, atol=1e-7)
        assert fr.wraps == (case == "on_screen")
        finite_frame(fr)
        frb = epipolar_frame(cam, light_toward_pixel(cam, *e[name], kind=kind, behind=True))
        assert frb.case == "behind" and frb.in_image == fr.in_image
        np.testing.assert_allclose(frb.epipole, e[name], rtol=1e-6, atol=1e-7)
    for a in (0.0, 37.0, 90.0, 180.0, -135.0):
        fr = epipolar_frame(cam, light_parallel_to_image(cam, a, kind=kind))
        assert fr.case == "at_infinity" and not fr.in_image
        finite_frame(fr)
        np.testing.assert_allclose(fr.direction, [math.cos(math.radians(a)), math.sin(math.radians(a))],
                                   atol=1e-9)
    # along the optical axis
    fr = epipolar_frame(cam, ("directional", cam.forward))
    assert fr.case == "on_screen"
    np.testing.assert_allclose(fr.epipole, [16, 12], atol=1e-9)
    finite_frame(fr)


def test_light_at_eye_is_finite():
    cam = rotated_camera(width=16, height=12)
    fr = epipolar_frame(cam, ("point", cam.origin))
    finite_frame(fr)


def test_bad_lights_raise():
    cam = rotated_camera(width=16, height=12)
    with pytest.raises(ValueError):
        epipolar_frame(cam, ("area", (0, 0, 1)))
    with pytest.raises(ValueError):
        epipolar_frame(cam, ("directional", (0, 0, 0)))


# -- coordinates -------------------------------------------------------------

@SETTINGS
@given(scenario_strategy(), st.integers(0, 2**31 - 1))
def test_world_rectified_world_round_trip(sc, seed):
    cam, light, label = sc
    fr = epipolar_frame(cam, light)
    finite_frame(fr)
    rng = np.random.default_rng(seed)
    p = points_around(fr, rng)
    scale = np.linalg.norm(p - cam.origin, axis=1) + np.linalg.norm(cam.origin)
    # NumPy oracle, float64
    a, b, t = world_to_view_coords_reference(fr, p)
    np.testing.assert_allclose(view_coords_to_world_reference(fr, a, b, t), p, atol=1e-11 * scale.max())
    a2, g, u = world_to_light_coords_reference(fr, p)
    # (the oracle's arccos loses ~sqrt(eps) on the axis)
    lscale = scale.max() + (0 if fr.is_directional else np.linalg.norm(p - fr.light_position, axis=1).max())
    np.testing.assert_allclose(light_coords_to_world_reference(fr, a2, g, u), p, atol=1e-7 * lscale)
    # Dr.Jit, float32: within 1e-5 relative
    P = p3(p)
    a, b, t = world_to_view_coords(fr, P)
    q = np3(view_coords_to_world(fr, a, b, t))
    assert np.all(np.isfinite(q)), label
    assert np.all(np.linalg.norm(q - p, axis=1) <= 1e-5 * scale), label
    a, g, u = world_to_light_coords(fr, P)
    q = np3(light_coords_to_world(fr, a, g, u))
    assert np.all(np.isfinite(q)), label
    if fr.is_directional:
        assert np.all(np.linalg.norm(q - p, axis=1) <= 1e-5 * scale), label
    else:   # relative to the light distance as well (spherical around p_l)
        sl = scale + np.linalg.norm(p - fr.light_position, axis=1)
        assert np.all(np.linalg.norm(q - p, axis=1) <= 1e-5 * sl), label


@SETTINGS
@given(scenario_strategy(), st.integers(0, 2**31 - 1))
def test_coords_fast_match_reference(sc, seed):
    cam, light, label = sc
    fr = epipolar_frame(cam, light)
    rng = np.random.default_rng(seed)
    p = points_around(fr, rng).astype(np.float32).astype(np.float64)   # what the fast path sees
    a_r, b_r, t_r = world_to_view_coords_reference(fr, p)
    a_f, b_f, t_f = (np.asarray(v) for v in world_to_view_coords(fr, p3(p)))
    # float32 eye position and point: direction error ~ ulp(|o| + t) / t
    ang_tol = 2e-5 + 3e-7 * (np.linalg.norm(cam.origin) + t_r) / t_r
    assert np.all(np.abs(b_f - b_r) <= ang_tol), label
    np.testing.assert_allclose(t_f, t_r, rtol=2e-6, atol=1e-6 * (1 + np.linalg.norm(cam.origin)))
    ok = np.sin(b_r) > 1e-2                      # alpha is undefined on the axis
    dang = np.angle(np.exp(1j * (a_f[ok] - a_r[ok])))
    assert np.all(np.abs(dang) < 20 * ang_tol[ok]), label
    # light side
    _, g_r, u_r = world_to_light_coords_reference(fr, p)
    _, g_f, u_f = (np.asarray(v) for v in world_to_light_coords(fr, p3(p)))
    lscale = np.maximum(np.abs(u_r), 1.0) + np.linalg.norm(cam.origin)
    if fr.is_directional:
        np.testing.assert_allclose(g_f, g_r, atol=1e-5 * lscale.max())
        # u = gamma cot(beta) (DESIGN §1)
        np.testing.assert_allclose(u_r[ok], g_r[ok] / np.tan(b_r[ok]), atol=1e-9 * lscale.max())
    else:
        # gamma is undefined at the light itself
        okg = u_r > 1e-2 * (1 + fr.light_distance)
        assert np.all((np.abs(g_f - g_r) <= 5 * ang_tol * (1 + t_r / fr.light_distance))[okg]), label
    np.testing.assert_allclose(u_f, u_r, atol=1e-5 * lscale.max())
    # in-slice conversions
    gv_r, uv_r = view_to_light_reference(fr, a_r, b_r, t_r)
    gv_f, uv_f = (np.asarray(v) for v in view_to_light(fr, mi.Float(a_r), mi.Float(b_r), mi.Float(t_r)))
    np.testing.assert_allclose(gv_r, g_r, atol=3e-7 * lscale.max())  # oracle arccos on the axis
    if fr.is_directional:
        np.testing.assert_allclose(gv_f, g_r, atol=2e-4 * lscale.max())
    else:
        assert np.all((np.abs(gv_f - g_r) <= 2e-4 + 1e-6 * t_r / u_r)[okg]), label
    np.testing.assert_allclose(uv_f, u_r, atol=2e-5 * lscale.max())
    bl_r, tl_r = light_to_view_reference(fr, a_r, g_r, u_r)
    np.testing.assert_allclose(bl_r, b_r, atol=1e-7)
    bl_f, tl_f = (np.asarray(v) for v in light_to_view(fr, mi.Float(a_r), mi.Float(g_r), mi.Float(u_r)))
    # float32 (gamma, u) around a point light: cancellation ~ ulp(L) / t
    far = 0.0 if fr.is_directional else fr.light_distance + u_r
    assert np.all(np.abs(bl_f - b_r) <= 2e-4 + 1e-6 * far / t_r), label
    assert np.all(np.abs(tl_f - t_r) <= 2e-5 * lscale + 1e-6 * far), label


@SETTINGS
@given(scenario_strategy(), st.integers(0, 2**31 - 1))
def test_ray_meeting_t(sc, seed):
    cam, light, label = sc
    fr = epipolar_frame(cam, light)
    rng = np.random.default_rng(seed)
    p = points_around(fr, rng, 60)
    _, b, t = world_to_view_coords_reference(fr, p)
    _, g, _ = world_to_light_coords_reference(fr, p)
    keep = (np.sin(b) > 1e-2) & (np.sin(g) > 1e-2)
    t_r, valid_r = ray_meeting_t_reference(fr, b[keep], g[keep])
    assert valid_r.all()
    np.testing.assert_allclose(t_r, t[keep], rtol=1e-6)
    t_f, valid_f = ray_meeting_t(fr, mi.Float(b[keep]), mi.Float(g[keep]))
    assert np.asarray(valid_f).all()
    np.testing.assert_allclose(np.asarray(t_f), t[keep], rtol=2e-3)
    # non-meeting rays of a point light give valid = False, t finite
    if not fr.is_directional:
        t_f, valid_f = ray_meeting_t(fr, mi.Float([2.0, 0.0]), mi.Float([2.0, 0.0]))
        assert not np.asarray(valid_f).any() and np.all(np.isfinite(np.asarray(t_f)))


@SETTINGS
@given(scenario_strategy())
def test_pixel_alpha_beta(sc):
    cam, light, label = sc
    fr = epipolar_frame(cam, light)
    x, y = pixel_centres(cam.width, cam.height)
    a_f, b_f = pixel_to_alpha_beta(fr, x, y)
    a_r, b_r = pixel_to_alpha_beta_reference(fr, np.asarray(x), np.asarray(y))
    assert np.all(np.isfinite(np.asarray(a_f))) and np.all(np.isfinite(np.asarray(b_f)))
    np.testing.assert_allclose(np.asarray(b_f), b_r, atol=5e-5)
    # back to pixels
    px, py, z = alpha_beta_to_pixel(fr, a_f, b_f)
    assert np.all(np.asarray(z) > 0)
    np.testing.assert_allclose(np.asarray(px), np.asarray(x), atol=2e-3 * max(cam.width, 1))
    np.testing.assert_allclose(np.asarray(py), np.asarray(y), atol=2e-3 * max(cam.width, 1))
    # the slice of the image centre is alpha = 0
    a_c, _ = direction_to_alpha_beta_reference(fr, cam.forward)
    if np.linalg.norm(np.cross(cam.forward, fr.axis)) > 1e-3:
        assert abs(a_c) < 1e-9


# -- ring ----------------------------------------------------------------------

@SETTINGS
@given(scenario_strategy(), st.floats(0.5, 10.0))
def test_ring_matches_reference(sc, ring_deg):
    cam, light, label = sc
    fr = epipolar_frame(cam, light)
    fast = np.asarray(ring_mask(fr, ring_deg)).reshape(cam.height, cam.width)
    ref = ring_mask_reference(fr, ring_deg)
    # disagreements only within float32 noise of the ring's edge
    yy, xx = np.mgrid[0:cam.height, 0:cam.width]
    d = cam.direction(xx + 0.5, yy + 0.5)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    ang = np.degrees(np.arccos(np.clip(np.abs(d @ fr.axis), 0, 1)))
    bad = fast != ref
    assert np.all(np.abs(ang[bad] - ring_deg) < 1e-2), label
    if not fr.in_image:
        # off screen beyond the ring's reach: empty
        from rectify import frustum_axis_angle
        if frustum_axis_angle(fr) > ring_deg + 0.5:
            assert not ref.any() and not fast.any()


def test_ring_centre_and_far():
    cam = rotated_camera(width=64, height=48, fov_x_deg=40)
    fr = epipolar_frame(cam, light_toward_pixel(cam, 32, 24))
    m = np.asarray(ring_mask(fr)).reshape(48, 64)
    assert m[23:25, 31:33].all() and m.sum() < 64 * 48 / 20
    fr = epipolar_frame(cam, light_toward_pixel(cam, -200, 24))
    assert not np.asarray(ring_mask(fr)).any()


# -- describe -----------------------------------------------------------------

def test_describe_is_plain_and_finite():
    cam = rotated_camera(width=32, height=24)
    for light in (light_toward_pixel(cam, 10, 5), light_parallel_to_image(cam, 30),
                  light_toward_pixel(cam, 10, 5, "point", behind=True)):
        d = describe(cam, light)
        for k in ("epipole_px", "slices_sinh", "slices_uniform", "max_distance_px_sinh", "ring_pixels"):
            assert k in d
        assert d["max_distance_px_sinh"] <= 0.5 + 2e-4
        assert np.all(np.isfinite(d["epipole_px"]))
        assert isinstance(d["slices_sinh"], int) and isinstance(d["ring_pixels"], int)
