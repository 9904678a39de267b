"""A point or spot light straight behind the camera: the anti-epipole lies on
the centre pixel of an odd-sized image, whose view ray runs (to float
rounding) along the direction from the light.

Along that ray the angle θ = atan2(t − t0, b) the ray subtends at the light
stays within float32's spacing of π/2 (b, the ray's distance to the light,
is ~1e-7 of its distance), and ``core.marching.march_bisected`` -- the working
reference (``boundary_bisections``) and the epipolar methods' ring and
re-marched samples (``ring_bisections``) -- took its ∫ dt / r² as the
difference of two such angles: 0, a black anti-epipole pixel (or a few
float spacings over a much smaller angle: up to 1.9× the peak).  The exact
reference and epipolar_tree / fourier_filter were black there alike, and
minmax_epipolar's fix-up march wrong next to it.

Each method at its defaults is compared with the exact working reference,
and that reference with a uniform-spacing midpoint march (no angles at all).
"""
import math

import mitsuba as mi
import numpy as np
import pytest

from episcatter.metrics import max_error_over_peak, scale_free_relmse
from episcatter.reference import exact_props, render_rgb
from tests.conftest import T, scene_dict

#: odd: the optical axis (and so the anti-epipole) is a pixel centre
RES = (37, 23)
CAMERA = {"origin": [0.0, 0.5, 3.0], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0]}
METHODS = ("epipolar_tree", "fourier_filter", "minmax_epipolar")


def _axis():
    o, t = np.array(CAMERA["origin"]), np.array(CAMERA["target"])
    return o, (t - o) / np.linalg.norm(t - o)


def _light(kind):
    """The light 0.6 behind the eye on the optical axis (a spot aimed along it)."""
    o, fwd = _axis()
    pos = o - 0.6 * fwd
    if kind == "point":
        return {"type": "point", "position": pos.tolist(), "intensity": 10}
    return {"type": "spot", "intensity": 20, "cutoff_angle": 35, "beam_width": 25,
            "to_world": T().look_at(origin=pos.tolist(), target=(pos + fwd).tolist(),
                                    up=[0, 1, 0])}


def _render(scene, kind, **props):
    return render_rgb(scene, mi.load_dict({"type": kind, "output": "scattering", **props}),
                      spp=1)


@pytest.fixture(scope="module", params=["point", "spot"])
def behind(request):
    """(scene, exact reference, uniform midpoint march) of one light kind."""
    scene = mi.load_dict(scene_dict(light=_light(request.param), res=RES, camera=CAMERA))
    exact = _render(scene, "raymarch", **exact_props(2048))
    uniform = _render(scene, "raymarch", visibility="exact", steps=4096, spacing="uniform")
    return scene, exact, uniform


def test_light_is_straight_behind():
    """The geometry the module doc describes: 180° from the view direction."""
    o, fwd = _axis()
    q = np.array(_light("point")["position"]) - o
    assert math.degrees(math.acos(q @ fwd / np.linalg.norm(q))) > 179.999


def test_exact_reference_at_the_anti_epipole(behind):
    """The bisected reference agrees with a march that measures no angles,
    and the anti-epipole pixel is lit (it was black)."""
    _, exact, uniform = behind
    cy, cx = RES[1] // 2, RES[0] // 2
    assert exact[cy, cx].max() > 0.5 * uniform[cy, cx].max() > 0.0
    assert max_error_over_peak(exact, uniform) <= 1e-2


@pytest.mark.parametrize("method", METHODS)
def test_methods_with_light_behind_camera(behind, method):
    scene, exact, uniform = behind
    img = _render(scene, method)
    assert np.all(np.isfinite(img))
    for ref in (exact, uniform):
        assert max_error_over_peak(img, ref) <= 0.5
        assert scale_free_relmse(img, ref) <= 1e-2


@pytest.mark.parametrize("offset", [1.7e-6, 1.7e-5, 1.7e-4])
def test_midpoint_marcher_with_light_just_off_the_anti_epipole(offset):
    """The plain midpoint march (``raymarch`` at its defaults, equiangular
    steps; the ring with ``ring_bisections=0``) on a ray that passes
    ``offset`` rad from the direction away from a point light behind the
    camera: its step boundaries and inverse-square correction were
    differences of angles within float32's spacing of π/2 there (0.33–0.93
    of the peak)."""
    o, fwd = _axis()
    side = np.cross(fwd, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    pos = o - 0.6 * (fwd + offset * side)
    light = {"type": "point", "position": pos.tolist(), "intensity": 10}
    scene = mi.load_dict(scene_dict(light=light, res=RES, camera=CAMERA))
    uniform = _render(scene, "raymarch", visibility="exact", steps=4096, spacing="uniform")
    img = _render(scene, "raymarch", visibility="exact")
    assert max_error_over_peak(img, uniform) <= 0.05
    assert scale_free_relmse(img, uniform) <= 1e-2
