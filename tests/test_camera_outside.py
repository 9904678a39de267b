"""A camera outside the fog volume (the sensor has no medium; a null-BSDF
boundary bounds it): each view ray's integral runs from where it enters the
medium to the surface or the exit.

Oracles: ``volpath`` (``max_depth=2``) within its noise for the exact
marcher, and the exact marcher for every other integrator."""
from __future__ import annotations

import warnings

import mitsuba as mi
import numpy as np
import pytest

from episcatter.metrics import scale_free_relmse
from integrators.core.scene_params import SceneParams
from tests.conftest import scene_dict
from tests.oracles import assert_agrees_with_volpath


METHODS = ["raymarch", "epipolar_tree", "fourier_filter", "minmax_epipolar"]


def outside(light="directional", res=(24, 18), box_scale=1.2, **kw):
    """The test scene with a small fog box (half-size ``box_scale``) the
    camera at (0, 0.5, 3) looks at from outside; the floor reaches beyond it."""
    d = scene_dict(light=light, res=res, box_scale=box_scale, **kw)
    del d["sensor"]["medium"]
    return mi.load_dict(d)


def test_the_camera_outside_is_read_as_such():
    params = SceneParams.from_scene(outside())
    assert params.camera_outside
    assert not SceneParams.from_scene(mi.load_dict(scene_dict())).camera_outside


@pytest.mark.parametrize("light", ["directional", "point", "spot_textured"])
def test_exact_marcher_from_outside_agrees_with_volpath(light):
    """Mean within 1 %, relMSE after 4x4 blocks within twice volpath's own
    noise (16 chunks of 1,024 spp): the entry point, the transmittance from
    it and the unfogged surfaces outside the box are Mitsuba's."""
    assert_agrees_with_volpath(outside(light))


@pytest.mark.parametrize("light", ["directional", "point", "spot"])
@pytest.mark.parametrize("method", METHODS)
def test_every_integrator_renders_from_outside(method, light):
    """Against the exact marcher (1,024 steps, pixel centres); the epipolar
    methods march every pixel from outside and say so."""
    scene = outside(light, res=(32, 24))
    ref = np.array(mi.load_dict({"type": "raymarch", "visibility": "exact", "steps": 1024})
                   .render_layers(scene, spp=1)["scattering"])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = mi.load_dict({"type": method}).render_layers(scene, spp=1)
    img = np.array(result["scattering"])
    assert ref.max() > 0 and np.all(np.isfinite(img))
    assert scale_free_relmse(img, ref) < 1e-4
    said = [str(w.message) for w in caught if "outside the medium" in str(w.message)]
    assert bool(said) == (method != "raymarch")


def test_rays_that_miss_the_fog_see_no_fog_and_no_attenuation():
    """A ray missing the box scatters nothing and its surface is seen
    unattenuated (T_cam = 1)."""
    scene = outside(res=(32, 24), box_scale=0.6)
    layers = mi.load_dict({"type": "raymarch", "visibility": "exact"}).render_layers(scene, spp=1)
    scat = np.array(layers["scattering"])[..., 0]
    assert scat.max() > 0 and (scat == 0).sum() > 0.3 * scat.size
    t_in = np.array(layers.capture.t_in)
    T = np.array(layers.capture.T_cam)[0]
    missed = np.isinf(t_in)
    assert missed.sum() > 0.3 * t_in.size and np.all(T[missed] == 1)
    assert np.all(scat.ravel()[missed] == 0)


@pytest.mark.parametrize("method", ["raymarch", "epipolar_tree", "minmax_epipolar"])
def test_a_partial_render_from_outside_equals_the_full_render_there(method):
    scene = outside(res=(20, 15))
    integ = mi.load_dict({"type": method, **({"visibility": "exact"}
                                             if method == "raymarch" else {})})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        full = np.array(integ.render_layers(scene, spp=1)["full"]).reshape(-1, 3)
        mask = np.random.default_rng(5).random(300) < 0.3
        part = integ.render_layers(scene, spp=1, samples=mask)
    computed = np.array(part.samples, dtype=bool)
    assert computed[mask].all()
    b = np.array(part["full"]).reshape(-1, 3)
    np.testing.assert_allclose(b[computed], full[computed], rtol=1e-6, atol=1e-7 * full.max())


def test_camera_outside_with_the_medium_on_the_sensor_names_the_fix():
    with pytest.raises(ValueError, match="remove the medium <ref> from the <sensor>"):
        SceneParams.from_scene(mi.load_dict(scene_dict(box_scale=1.2)))


def test_two_media_are_refused():
    d = scene_dict(box_scale=1.2)
    del d["sensor"]["medium"]
    d["medium2"] = {"type": "homogeneous", "id": "medium2", "sigma_t": 0.5}
    d["box2"] = {"type": "sphere", "center": [0, 0, -3], "radius": 0.5,
                 "bsdf": {"type": "null"}, "interior": {"type": "ref", "id": "medium2"}}
    with pytest.raises(ValueError, match="bounds 2 media"):
        SceneParams.from_scene(mi.load_dict(d))


@pytest.mark.parametrize("light", ["directional", "point"])
def test_minmax_marches_from_outside_as_the_other_epipolar_methods_do(light):
    """From outside every epipolar method marches every pixel with the same
    exact marcher at the ring's steps (thick random scenes, seeds 181 and
    262, were 2-5 % dark at minmax's 128 fix-up steps)."""
    scene = outside(light, res=(20, 15), sigma_t=2.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tree = np.array(mi.load_dict({"type": "epipolar_tree"})
                        .render_layers(scene, spp=1)["scattering"])
        minmax = np.array(mi.load_dict({"type": "minmax_epipolar"})
                          .render_layers(scene, spp=1)["scattering"])
    np.testing.assert_allclose(minmax, tree, rtol=1e-5, atol=1e-7 * tree.max())
