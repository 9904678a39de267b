"""Mitsuba's conventions in the render template (issue 10, defect 7) and
boolean properties given as strings (defect 5)."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from integrators.core.properties import read_bool
from tests.conftest import scene_dict

FAST = {"type": "raymarch", "steps": 4, "visibility": "exact"}


def tiny(sample_count=1, **kw):
    d = scene_dict(res=(8, 6), **kw)
    d["sensor"]["sampler"] = {"type": "independent", "sample_count": sample_count}
    return mi.load_dict(d)


def test_sensor_sample_count_is_honoured():
    scene = tiny(sample_count=4)
    integ = mi.load_dict(FAST)
    assert integ.sample_count(scene) == 4
    img = np.array(mi.render(scene, integrator=integ))
    np.testing.assert_array_equal(img, np.array(integ.render_layers(scene, spp=4)["full"]))
    assert not np.array_equal(img, np.array(integ.render_layers(scene, spp=1)["full"]))
    # the property and mi.render's spp override the sampler
    assert mi.load_dict({**FAST, "samples_per_pixel": 2}).sample_count(scene) == 2
    assert integ.sample_count(scene, spp=3) == 3
    with pytest.raises(ValueError, match="spp"):
        integ.sample_count(scene, spp=-3)


def test_film_holds_the_image_and_the_layers_after_mi_render():
    scene = tiny()
    integ = mi.load_dict(FAST)
    img = np.array(mi.render(scene, integrator=integ))
    film = scene.sensors()[0].film()
    bitmap = film.bitmap()
    names = [bitmap.struct_()[i].name for i in range(bitmap.channel_count())]
    assert names[:3] == ["R", "G", "B"] and integ.aov_names() == names[3:]
    assert "scattering.R" in names and "distance.Y" in names
    data = np.array(bitmap)
    layers = integ.render_layers(scene)
    np.testing.assert_array_equal(data[..., :3], img)
    np.testing.assert_allclose(data[..., 3:6], np.array(layers["scattering"]), rtol=1e-6)
    np.testing.assert_allclose(np.array(film.develop())[..., :3], img, rtol=1e-6)


def test_scattering_output_moves_full_into_the_aovs():
    integ = mi.load_dict({**FAST, "output": "scattering"})
    assert integ.aov_names()[:3] == ["full.R", "full.G", "full.B"]


def test_aov_integrator_refuses_clearly():
    wrapper = mi.load_dict({"type": "aov", "aovs": "dd.y:depth", "inner": FAST})
    with pytest.raises(RuntimeError) as info:
        mi.render(tiny(), integrator=wrapper)
    assert isinstance(info.value.__cause__, NotImplementedError)
    assert "aov" in str(info.value.__cause__) and "AOVs of the film" in str(info.value.__cause__)


def test_traverse_lists_the_properties_read_only():
    params = mi.traverse(mi.load_dict({**FAST, "steps": 7}))
    assert params["steps"] == 7 and params["visibility"] == "exact"
    assert "timings" not in params
    with pytest.raises(Exception, match="Read-Only"):
        params["steps"] = 8


def test_backward_pass_says_derivatives_are_not_supported():
    scene = tiny()
    params = mi.traverse(scene)
    key = "medium.sigma_t.value.value"
    dr.enable_grad(params[key])
    params.update()
    img = mi.render(scene, params=params, integrator=mi.load_dict(FAST))
    with pytest.raises(Exception) as info:
        dr.backward(dr.mean(img, axis=None))
    text = f"{info.value} {info.value.__cause__}"
    assert "derivatives are not supported" in text


@pytest.mark.parametrize("text, value", [("false", False), ("False", False), ("no", False),
                                         ("0", False), ("off", False), ("true", True),
                                         ("YES", True), ("1", True), ("on", True)])
def test_read_bool_accepts_mitsubas_strings(text, value):
    assert read_bool({"x": text}, "x", not value) is value


@pytest.mark.parametrize("bad", ["maybe", "", 2, 0.0])
def test_read_bool_refuses_anything_else(bad):
    with pytest.raises(ValueError, match="must be a boolean"):
        read_bool({"x": bad}, "x", False)


def test_raymarch_jitter_false_string_is_false():
    """`-p jitter=no` / <string name="jitter" value="false"/> turned jitter on."""
    assert mi.load_dict({"type": "raymarch", "jitter": "false"}).jitter is False
    assert mi.load_dict({"type": "raymarch", "jitter": "no"}).jitter is False
    assert mi.load_dict({"type": "raymarch", "jitter": "true"}).jitter is True
    with pytest.raises(Exception, match="must be a boolean"):
        mi.load_dict({"type": "raymarch", "jitter": "maybe"})


@pytest.mark.parametrize("kind", ["epipolar_tree", "fourier_filter"])
def test_automatic_slices_follow_the_samples(kind):
    """Without ``slice_spacing`` the slices are 1/√spp px apart at spp
    jittered samples per pixel (the same image as that explicit spacing),
    1 px at one sample or at un-jittered ones; an explicit spacing wins.
    (They stayed 1 px apart at any spp: antialiased renders did not gain
    from their samples, issue 16.)"""
    scene = tiny()
    auto = mi.load_dict({"type": kind})
    for spp, spacing in ((4, 0.5), (16, 0.25)):
        a = np.array(auto.render_layers(scene, spp=spp)["full"])
        b = np.array(mi.load_dict({"type": kind, "slice_spacing": spacing})
                     .render_layers(scene, spp=spp)["full"])
        np.testing.assert_array_equal(a, b)
    one = np.array(auto.render_layers(scene, spp=1)["full"])
    np.testing.assert_array_equal(one, np.array(mi.load_dict(
        {"type": kind, "slice_spacing": 1.0}).render_layers(scene, spp=1)["full"]))
    still = mi.load_dict({"type": kind, "jitter_pixels": False})
    np.testing.assert_array_equal(
        np.array(still.render_layers(scene, spp=4)["full"]),
        np.array(mi.load_dict({"type": kind, "jitter_pixels": False, "slice_spacing": 1.0})
                 .render_layers(scene, spp=4)["full"]))
    cap = type("Cap", (), {"spp": 16})()
    assert auto.slice_spacing_for(cap) == 0.25
    assert mi.load_dict({"type": kind, "slice_spacing": 2.0}).slice_spacing_for(cap) == 2.0
