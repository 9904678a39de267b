"""epipolar_tree (Baran et al. 2010) against raymarch with exact visibility."""

import mitsuba as mi
import numpy as np
import pytest

from episcatter.metrics import relmse
from integrators.epipolar_setup import epipolar_frame_of
from integrators.scene_params import SceneParams
from tests.conftest import scene_dict

RES = (32, 24)
LOOK_UP = {"origin": [0, 0.5, 3], "target": [0, 1.5, 0], "up": [0, 1, 0]}
DEFAULT_CAMERA = {"origin": [0, 0.5, 3], "target": [0, 0, 0], "up": [0, 1, 0]}

#: coarse -> fine: slices, light rays, SVD rank and prefiltering all grow
SETTINGS = [
    dict(slices=12, light_rays=24, svd_rank=1, prefilter=1),
    dict(slices=48, light_rays=96, svd_rank=3, prefilter=2),
    dict(slices=400, light_rays=400, svd_tolerance=1e-5, prefilter=4, ring_steps=2048),
]


def directional(toward_scene, irradiance=2.0):
    """A directional light travelling along ``toward_scene``."""
    return {"type": "directional", "direction": list(map(float, toward_scene)),
            "irradiance": irradiance}


def camera_axes(camera):
    o, t = np.array(camera["origin"], float), np.array(camera["target"], float)
    fwd = (t - o) / np.linalg.norm(t - o)
    up_perp = np.array(camera["up"], float) - (np.array(camera["up"], float) @ fwd) * fwd
    return fwd, up_perp / np.linalg.norm(up_perp)


def parallel_light():
    """Light direction orthogonal to the optical axis: epipole at infinity."""
    fwd, up = camera_axes(DEFAULT_CAMERA)
    right = np.cross(fwd, up)
    return directional(-(0.6 * up + 0.8 * right))


def light_through_pixel_centre(px, py, camera=LOOK_UP):
    """The light seen exactly at pixel centre (px, py): the epipole is there."""
    scene = mi.load_dict(scene_dict(res=RES, camera=camera))
    d = SceneParams.from_scene(scene).camera.direction(px, py)
    return directional(-d / np.linalg.norm(d))


SCENES = {
    # anti-epipole (light behind the camera) off screen
    "behind_off_screen": dict(),
    # light in front of the camera, epipole inside the image
    "on_screen": dict(light=directional([0.05, -0.25, 1.0]), camera=LOOK_UP),
    # light behind the camera, anti-epipole inside the image
    "away_on_screen": dict(light=directional([0.1, -0.3, -1.0])),
    "epipole_on_pixel_centre": dict(light=light_through_pixel_centre(16.5, 12.5), camera=LOOK_UP),
    "parallel_to_image": dict(light=parallel_light()),
}


def render(scene, integrator, **props):
    integ = mi.load_dict({"type": integrator, "output": "scattering", **props})
    return np.array(integ.render(scene)), integ


def reference(scene):
    return render(scene, "raymarch", visibility="exact", steps=2048)[0]


def normalised_relmse(img, ref):
    """relMSE of images scaled to mean 1 (its eps is then 1% of the mean)."""
    s = 1.0 / ref.mean()
    return relmse(img * s, ref * s)


def test_scenarios_are_what_they_say():
    cases = {}
    for name, kw in SCENES.items():
        scene = mi.load_dict(scene_dict(res=RES, **kw))
        cases[name] = epipolar_frame_of(SceneParams.from_scene(scene))
    assert cases["behind_off_screen"].case == "behind" and not cases["behind_off_screen"].in_image
    assert cases["on_screen"].case == "on_screen"
    assert cases["away_on_screen"].case == "behind" and cases["away_on_screen"].in_image
    np.testing.assert_allclose(cases["epipole_on_pixel_centre"].epipole, [16.5, 12.5], atol=1e-3)
    fr = cases["parallel_to_image"]
    assert fr.case == "at_infinity" or np.linalg.norm(fr.epipole - [16, 12]) > 1e5


@pytest.mark.parametrize("name,phase", [
    ("behind_off_screen", None),
    ("on_screen", None),
    ("on_screen", {"type": "hg", "g": 0.5}),
    ("away_on_screen", {"type": "hg", "g": -0.5}),
    ("away_on_screen", None),
    ("epipole_on_pixel_centre", None),
    ("parallel_to_image", {"type": "hg", "g": 0.5}),
])
def test_converges_to_exact_raymarch(name, phase):
    scene = mi.load_dict(scene_dict(res=RES, phase=phase, **SCENES[name]))
    ref = reference(scene)
    errors = [normalised_relmse(render(scene, "epipolar_tree", **s)[0], ref) for s in SETTINGS]
    assert errors[-1] < errors[0], errors
    assert errors[-1] < 1e-3, errors


def test_default_settings_are_close():
    scene = mi.load_dict(scene_dict(res=RES, **SCENES["on_screen"]))
    img, integ = render(scene, "epipolar_tree")
    assert normalised_relmse(img, reference(scene)) < 3e-3
    for stage in ("rectify", "blockers", "svd", "sweep", "unrectify", "ring"):
        assert stage in integ.timings


@pytest.mark.parametrize("sigma_t", [{"type": "rgb", "value": [0.1, 0.3, 0.9]}, 0.5])
def test_unshadowed_medium_matches_the_closed_form(sigma_t):
    """No blocker at all: the rectified sum (the kernel's closed-form path)
    equals ∫ σs f_p E e^{-σt τ(x(t))} e^{-σt t} dt per pixel.  Many slices:
    a sample takes the light-side factor e^{-σt h(α, γ)} of its nearest
    slice, off by up to half a slice spacing (1.5 % here with the ~30
    automatic slices of an 8×6 image)."""
    res = (8, 6)
    d = scene_dict(surface=0.0, blocker=None, floor=None, res=res, sigma_t=sigma_t)
    scene = mi.load_dict(d)
    p = SceneParams.from_scene(scene)
    out, _ = render(scene, "epipolar_tree", slices=400, light_rays=512, svd_tolerance=1e-6)
    cam, med = p.camera, p.medium
    ys, xs = np.mgrid[0:res[1], 0:res[0]] + 0.5
    omega = cam.direction(xs.ravel(), ys.ravel())
    omega /= np.linalg.norm(omega, axis=1, keepdims=True)
    o = cam.origin + omega * (cam.near_clip / (omega @ cam.forward))[:, None]

    def box_exit(p0, w):
        with np.errstate(divide="ignore"):
            t0, t1 = (med.bounds_min - p0) / w, (med.bounds_max - p0) / w
        return np.min(np.maximum(t0, t1), axis=-1)

    expected = []
    for oi, wi in zip(o, omega):
        d_exit = box_exit(oi, wi)
        t = (np.arange(100000) + 0.5) / 100000 * d_exit
        tau = box_exit(oi + t[:, None] * wi, np.broadcast_to(p.light.direction, (t.size, 3)))
        f = np.exp(-med.sigma_t[None] * (t + tau)[:, None])
        expected.append(f.mean(0) * d_exit * med.sigma_s / (4 * np.pi) * 2.0)
    expected = np.array(expected).reshape(res[1], res[0], 3)
    np.testing.assert_allclose(out, expected, rtol=2e-3)


@pytest.mark.parametrize("sigma_t", [1e-4, 1e-2, 1.0, 10.0])
@pytest.mark.parametrize("name", ["on_screen", "away_on_screen"])
def test_thin_and_thick_media_are_finite(sigma_t, name):
    scene = mi.load_dict(scene_dict(res=(16, 12), sigma_t=sigma_t, **SCENES[name]))
    integ = mi.load_dict({"type": "epipolar_tree"})
    layers = {k: np.array(v) for k, v in integ.render_layers(scene).items()}
    for key, img in layers.items():
        assert np.all(np.isfinite(img)) and np.all(img >= 0), key


def test_thick_medium_converges():
    scene = mi.load_dict(scene_dict(res=RES, sigma_t=10.0, **SCENES["away_on_screen"]))
    img, _ = render(scene, "epipolar_tree")
    assert normalised_relmse(img, reference(scene)) < 1e-3


def test_resampled_shadow_map_converges():
    scene = mi.load_dict(scene_dict(res=RES, **SCENES["on_screen"]))
    ref = reference(scene)
    errors = [normalised_relmse(render(scene, "epipolar_tree", rectification="resampled",
                                       shadowmap_resolution=res, slices=400, light_rays=400)[0],
                                ref) for res in (16, 1024)]
    assert errors[1] < errors[0] and errors[1] < 1e-3, errors


def test_full_output_adds_the_surface():
    scene = mi.load_dict(scene_dict(res=(16, 12)))
    tree = {k: np.array(v) for k, v in
            mi.load_dict({"type": "epipolar_tree"}).render_layers(scene).items()}
    march = {k: np.array(v) for k, v in
             mi.load_dict({"type": "raymarch", "visibility": "exact"}).render_layers(scene).items()}
    np.testing.assert_allclose(tree["full"], tree["surface"] + tree["scattering"], rtol=1e-6)
    np.testing.assert_allclose(tree["surface"], march["surface"], rtol=1e-6)


@pytest.mark.parametrize("light", ["point", "spot"])
def test_point_and_spot_lights_are_refused(light):
    scene = mi.load_dict(scene_dict(light=light, res=(8, 6)))
    with pytest.raises(ValueError, match="only directional lights are supported by epipolar_tree"):
        mi.load_dict({"type": "epipolar_tree"}).render(scene)


@pytest.mark.parametrize("props", [{"rectification": "warped"}, {"prefilter": 0},
                                   {"svd_tolerance": 0.0}, {"ring_degrees": -1.0},
                                   {"light_rays": 1.5}])
def test_invalid_properties(props):
    # Mitsuba's plugin loader re-raises the constructor's ValueError as RuntimeError
    with pytest.raises((ValueError, RuntimeError), match=f"Property '{next(iter(props))}'"):
        mi.load_dict({"type": "epipolar_tree", **props})
