"""raymarch: analytic segments, exact visibility, shadow-map convergence."""
import mitsuba as mi
import numpy as np
import pytest

from episcatter.metrics import relmse
from tests.conftest import scene_dict
from tests.oracles import unshadowed_directional


def render(scene, **props):
    integ = mi.load_dict({"type": "raymarch", **props})
    return {k: np.array(v) for k, v in integ.render_layers(scene).items()}


def test_unshadowed_homogeneous_slab_closed_form():
    """Directional light, no blockers: along a ray the light-side path τ is
    linear in t, so L_scat has a closed form; compare per pixel."""
    d = scene_dict(surface=0.0, blocker=None, floor=None, res=(8, 6), sigma_t=0.5,
                   phase={"type": "isotropic"})
    scene = mi.load_dict(d)
    from integrators.scene_params import SceneParams
    p = SceneParams.from_scene(scene)
    out = render(scene, visibility="exact", steps=4096, output="scattering")["scattering"]
    expected = unshadowed_directional(p, (8, 6), samples=200000)[..., 0]
    np.testing.assert_allclose(out[..., 0], expected, rtol=2e-3)


@pytest.mark.parametrize("light", ["directional", "spot_textured", "point"])
def test_shadowmap_converges_to_exact(light):
    scene = mi.load_dict(scene_dict(light=light, res=(24, 18)))
    exact = render(scene, visibility="exact", steps=128)["full"]
    errors = [relmse(render(scene, visibility="shadowmap", steps=128,
                            shadowmap_resolution=r)["full"], exact)
              for r in (16, 64, 512)]
    assert errors[2] < errors[0]
    assert errors[2] < 1e-4, errors


def test_steps_converge():
    scene = mi.load_dict(scene_dict(res=(16, 12)))
    fine = render(scene, visibility="exact", steps=2048)["full"]
    e = [relmse(render(scene, visibility="exact", steps=s)["full"], fine) for s in (8, 32, 128)]
    assert e[0] > e[1] > e[2]
    assert e[2] < 1e-4


@pytest.mark.parametrize("sigma_t", [1e-4, 1e-2, 1.0, 10.0])
@pytest.mark.parametrize("visibility", ["exact", "shadowmap"])
def test_thin_and_thick_media_are_finite(sigma_t, visibility):
    scene = mi.load_dict(scene_dict(sigma_t=sigma_t, res=(12, 9)))
    layers = render(scene, visibility=visibility, steps=32, shadowmap_resolution=64)
    for name, img in layers.items():
        assert np.all(np.isfinite(img)), name
        assert np.all(img >= 0), name


def test_full_is_surface_plus_scattering_and_outputs():
    scene = mi.load_dict(scene_dict(res=(12, 9)))
    layers = render(scene, visibility="exact", steps=32)
    np.testing.assert_allclose(layers["full"], layers["surface"] + layers["scattering"],
                               rtol=1e-5, atol=1e-7)
    scat = np.array(mi.render(scene, integrator=mi.load_dict(
        {"type": "raymarch", "visibility": "exact", "steps": 32, "output": "scattering"})))
    np.testing.assert_allclose(scat, layers["scattering"], rtol=1e-5, atol=1e-7)
    assert layers["distance"].shape == (9, 12, 1)


def test_samples_per_pixel_box_filter():
    scene = mi.load_dict(scene_dict(res=(8, 6)))
    one = render(scene, visibility="exact", steps=16)["full"]
    many = render(scene, visibility="exact", steps=16, samples_per_pixel=64)["full"]
    assert abs(many.mean() / one.mean() - 1) < 0.05
    assert not np.allclose(many, one)
