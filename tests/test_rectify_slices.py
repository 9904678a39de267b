"""Slice placement (uniform, Baran §8 sinh), pixel -> slice lookup, the
half-pixel bound, and the slice counts Baran reports for 1280x960."""
import math
import os

import mitsuba as mi
import numpy as np
import pytest
from hypothesis import given, settings

import integrators  # noqa: F401
from rectify import (distance_to_slices, distance_to_slices_reference, epipolar_frame,
                     max_distance_to_slices, max_distance_to_slices_reference, pixel_to_slice,
                     pixel_to_slice_reference, sinh_slices, slice_segments, slice_to_pixel,
                     slice_to_pixel_reference, uniform_slices)
from rectify.scenarios import (light_parallel_to_image, light_toward_pixel, nasty_epipoles,
                               rotated_camera)
from tests.strategies import scenario_strategy

#: RECTIFY_EXAMPLES=2000 for a long stress run
SETTINGS = settings(max_examples=int(os.environ.get("RECTIFY_EXAMPLES", 60)), deadline=None)
#: float32 slack of the fast distance (pixel centres can sit exactly 0.5 px
#: from two parallel slice lines)
F32 = 2e-4
#: float64 slack of the oracle: an epipole ~1e9 px away and merged
#: near-duplicate slices (ALPHA_MERGE) move lines by ~1e-6 px
F64 = 1e-5


def check_slices(fr, s):
    assert s.count >= 2
    assert np.all(np.isfinite(s.alpha)) and np.all(np.isfinite(s.points))
    assert np.all(np.diff(s.alpha) > 0)
    assert s.alpha[0] > -math.pi - 1e-12 and s.alpha[-1] <= math.pi + 1e-12
    W, H = fr.width, fr.height
    assert np.all((s.points >= -1e-9) & (s.points <= np.array([W, H]) + 1e-9))
    entry, exit_ = slice_segments(fr, s)
    for seg in (entry, exit_):
        assert np.all(np.isfinite(seg))
        assert np.all((seg >= -1e-6) & (seg <= np.array([W, H]) + 1e-6))


@SETTINGS
@given(scenario_strategy())
def test_half_pixel_bound(sc):
    cam, light, label = sc
    fr = epipolar_frame(cam, light)
    for s in (sinh_slices(fr), uniform_slices(fr)):
        check_slices(fr, s)
        ref = distance_to_slices_reference(fr, s)
        fast = np.asarray(distance_to_slices(fr, s)).reshape(ref.shape)
        assert np.all(np.isfinite(fast)), label
        assert ref.max() <= 0.5 + F64, (label, s.method, ref.max())
        assert fast.max() <= 0.5 + F32, (label, s.method, fast.max())
        # fast (two neighbouring slices) == brute force (all slices)
        np.testing.assert_allclose(fast, ref, atol=2e-3 * (1 + max(cam.width, cam.height) / 64))
    # sinh never needs more slices than uniform 1-px border spacing
    assert sinh_slices(fr).count <= uniform_slices(fr).count + 2


@SETTINGS
@given(scenario_strategy())
def test_spacing_bound(sc):
    """``spacing`` s (the slice interpolation's coarser placement): every
    pixel centre within s/2 px of a slice (the oracle's brute force), and
    about 1/s of the slices of s = 1."""
    cam, light, label = sc
    fr = epipolar_frame(cam, light)
    one = sinh_slices(fr).count
    for spacing in (1.5, 2.0, 3.0):
        s = sinh_slices(fr, spacing)
        check_slices(fr, s)
        ref = distance_to_slices_reference(fr, s)
        assert ref.max() <= 0.5 * spacing + F64, (label, spacing, ref.max())
        assert s.count <= one / spacing * 1.1 + 8, (label, spacing, s.count, one)


@pytest.mark.parametrize("size", [(1, 1), (3, 2)])
@pytest.mark.parametrize("epipole", [(0.35, 0.4), (0.1, 0.5), (0.5, 0.02)])
def test_fine_spacing_bounds_every_point_near_an_epipole_by_an_edge(size, epipole):
    """Small images are sliced at a fraction of a pixel (``spacing`` < 1) and
    antialiased samples lie anywhere in their pixel: every image point
    within spacing/2 of a slice.  An edge less than half a pixel from the
    epipole got its two corners only (the 1 px rule), leaving a wedge of up
    to 180° empty (nave_onscreen at 1x1, 64 spp: 97°, the mean 8.6 % low)."""
    W, H = size
    cam = rotated_camera((0.5, -1, 2), 15, 5, -20, 75, W, H)
    x, y = epipole[0] * W, epipole[1] * H
    spacing = 1.0 / 64
    rng = np.random.default_rng(1)
    pts = rng.random((4000, 2)) * np.array([W, H])
    for kind in ("directional", "point"):
        fr = epipolar_frame(cam, light_toward_pixel(cam, x, y, kind, distance=3.0))
        s = sinh_slices(fr, spacing)
        check_slices(fr, s)
        d = distance_to_slices_reference(fr, s, pts)
        assert d.max() <= 0.5 * spacing + F64, (kind, d.max())


def test_spacing_must_be_positive():
    cam = rotated_camera()
    fr = epipolar_frame(cam, light_toward_pixel(cam, 20.0, 14.0))
    with pytest.raises(ValueError, match="spacing"):
        sinh_slices(fr, 0.0)


@SETTINGS
@given(scenario_strategy())
def test_pixel_to_slice_matches_reference(sc):
    cam, light, label = sc
    fr = epipolar_frame(cam, light)
    s = sinh_slices(fr)
    s_f, beta_f, k0_f, k1_f, f_f = (np.asarray(v) for v in pixel_to_slice(fr, s))
    s_r, beta_r, k0_r, k1_r, f_r = pixel_to_slice_reference(fr, s)
    assert np.all(np.isfinite(s_f)) and np.all((f_f >= 0) & (f_f <= 1))
    np.testing.assert_allclose(beta_f, beta_r, atol=5e-5)
    S = s.count

    def alpha_of(k0, k1, f):
        a0, a1 = s.alpha[k0], s.alpha[k1]
        a1 = np.where(a1 < a0, a1 + 2 * np.pi, a1)      # across the wrap
        return a0 + f * (a1 - a0)

    # both describe the same angle (compare on the circle, off the axis)
    da = np.angle(np.exp(1j * (alpha_of(k0_f, k1_f, f_f) - alpha_of(k0_r, k1_r, f_r))))
    ok = np.sin(beta_r) > 1e-2
    assert np.all(np.abs(da[ok]) < 1e-4), label
    # and the neighbours are adjacent slices
    assert np.all((k1_f == k0_f + 1) | (s.wraps & (k0_f == S - 1) & (k1_f == 0)))
    # (s, beta) -> pixel is the inverse
    x, y, z = (np.asarray(v) for v in slice_to_pixel(fr, s, mi.Float(s_f), mi.Float(beta_f)))
    xr, yr, zr = slice_to_pixel_reference(fr, s, s_r, beta_r)
    yy, xx = np.mgrid[0:cam.height, 0:cam.width]
    tol = 2e-3 * max(cam.width, cam.height)
    for px, py in ((x, y), (xr, yr)):
        np.testing.assert_allclose(px, xx.ravel() + 0.5, atol=tol)
        np.testing.assert_allclose(py, yy.ravel() + 0.5, atol=tol)
    assert np.all(z > 0) and np.all(zr > 0)


@pytest.mark.parametrize("name", sorted(nasty_epipoles(16, 12)))
@pytest.mark.parametrize("behind", [False, True])
def test_nasty_epipoles_small(name, behind):
    cam = rotated_camera((0.5, -1, 2), 15, 5, -20, 75, 17, 13)
    x, y = nasty_epipoles(17, 13)[name]
    for kind in ("directional", "point"):
        fr = epipolar_frame(cam, light_toward_pixel(cam, x, y, kind, behind, distance=3.0))
        for s in (sinh_slices(fr), uniform_slices(fr)):
            check_slices(fr, s)
            assert max_distance_to_slices_reference(fr, s, 17, 13) <= 0.5 + F64
            assert max_distance_to_slices(fr, s) <= 0.5 + F32


@pytest.mark.parametrize("angle", [0.0, 90.0, 180.0, 270.0, 30.0, -45.0, 1e-7])
def test_at_infinity_parallel_slices(angle):
    cam = rotated_camera((0, 0, 0), 0, 0, 0, 60, 24, 16)
    fr = epipolar_frame(cam, light_parallel_to_image(cam, angle))
    assert fr.case == "at_infinity"
    for s in (sinh_slices(fr), uniform_slices(fr)):
        check_slices(fr, s)
        assert max_distance_to_slices_reference(fr, s) <= 0.5 + F64
        assert max_distance_to_slices(fr, s) <= 0.5 + F32
    # lines are parallel, 1 px apart: about (extent across the lines) + 1 slices
    d = np.array([math.cos(math.radians(angle)), math.sin(math.radians(angle))])
    extent = abs(d[1]) * 24 + abs(d[0]) * 16
    assert sinh_slices(fr).count <= math.ceil(extent) + 2


def test_off_screen_only_gets_crossing_slices():
    cam = rotated_camera(width=32, height=24)
    on = epipolar_frame(cam, light_toward_pixel(cam, 16, 12))
    off = epipolar_frame(cam, light_toward_pixel(cam, -40, 12))
    assert off.case == "off_screen" and not off.wraps
    s_on, s_off = uniform_slices(on), uniform_slices(off)
    # exit edges top + right + bottom only: 32 + 24 + 32 (+1 corner)
    assert s_off.count <= 32 + 24 + 32 + 1 < s_on.count
    entry, exit_ = slice_segments(off, s_off)
    assert np.all(np.linalg.norm(exit_ - entry, axis=1) >= 0)
    assert np.all(entry[:, 0] <= exit_[:, 0] + 1e-9)      # rays run away from the epipole


@pytest.mark.parametrize("where, epipole, expect", [
    ("centre", (640.0, 480.0), (0.10, 0.20)),        # Baran: ~15% fewer
    ("near corner", (64.0, 48.0), (0.40, 0.60)),     # Baran: about half
    ("corner", (1.0, 1.0), (0.45, 0.65)),
])
def test_baran_slice_counts_1280x960(where, epipole, expect):
    cam = rotated_camera((0, 0, 0), 0, 0, 0, 60, 1280, 960)
    fr = epipolar_frame(cam, light_toward_pixel(cam, *epipole))
    s, u = sinh_slices(fr), uniform_slices(fr)
    saving = 1 - s.count / u.count
    dist_s, dist_u = max_distance_to_slices(fr, s), max_distance_to_slices(fr, u)
    print(f"\n1280x960 epipole {where} {epipole}: sinh {s.count} slices, uniform {u.count}, "
          f"saving {100 * saving:.1f}%, max distance sinh {dist_s:.4f} px, uniform {dist_u:.4f} px")
    assert expect[0] <= saving <= expect[1]
    assert dist_s <= 0.5 + F32 and dist_u <= 0.5 + F32


@pytest.mark.parametrize("wraps", [False, True])
def test_first_above_matches_binary_search(wraps):
    """The binned lookup of alpha_to_slice = a binary search over the sorted
    table: random angles, the table's own entries (ties), values just
    beside them and outside the range; sinh-like uneven spacing."""
    from rectify.slices import _first_above
    rng = np.random.default_rng(3)
    table = np.sort(np.sinh(rng.uniform(-3, 3, 300)) * 0.2).astype(np.float32)
    if wraps:
        table = np.append(table, np.float32(table[0] + 2 * np.pi))
    alpha = np.concatenate([rng.uniform(table[0] - 1, table[-1] + 1, 5000), table,
                            np.nextafter(table, np.float32(-10)),
                            np.nextafter(table, np.float32(10))]).astype(np.float32)
    got = np.array(_first_above(table, mi.Float(table), mi.Float(alpha)))
    expected = np.minimum(np.searchsorted(table, alpha, side="right"), len(table) - 1)
    np.testing.assert_array_equal(got, expected)
