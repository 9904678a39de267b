"""Several emitters in one scene: every integrator renders the sum over its
lights (single scattering and direct surface lighting are linear in the
light), each light with its own epipolar geometry on one camera capture.

Oracles: the sum of the single-light renders of the same integrator (to
float rounding), and ``volpath`` (``max_depth=2``) within its noise."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from episcatter.motion import parse_motion
from episcatter.sequence import Sequence
from tests.conftest import LIGHTS, T, scene_dict
from tests.oracles import assert_agrees_with_volpath


RES = (32, 24)
#: six lights of every supported kind (after Klehm et al.'s six-spot scene,
#: with a sun and point lights added)
SIX = {
    "light": LIGHTS["directional"],
    "light2": LIGHTS["point"],
    "light3": LIGHTS["spot_textured"],
    "light4": {"type": "spot", "intensity": 12, "cutoff_angle": 20, "beam_width": 15,
               "to_world": T().look_at(origin=[-1.2, 2.2, 0.3], target=[-0.5, -1, 0],
                                       up=[0, 0, 1])},
    "light5": {"type": "directional", "direction": [-0.5, -1, 0.3], "irradiance": 0.7},
    "light6": {"type": "point", "position": [-0.8, 1.0, 1.2], "intensity": 3},
}
METHODS = ["raymarch", "epipolar_tree", "fourier_filter", "minmax_epipolar"]
LAYERS = ("full", "scattering", "surface", "distance")


def scene_of(names, res=RES, **kw):
    d = scene_dict(light=None, res=res, **kw)
    d.update({k: SIX[k] for k in names})
    return mi.load_dict(d)


def layers(integ, scene, **kw):
    return {k: np.array(v) for k, v in integ.render_layers(scene, **kw).items()}


def assert_sum(total, parts, layer):
    expected = sum(p[layer] for p in parts)
    np.testing.assert_allclose(total[layer], expected, rtol=2e-5,
                               atol=1e-6 * max(1e-30, float(np.abs(expected).max())),
                               err_msg=layer)


@pytest.mark.parametrize("k", [2, 6])
@pytest.mark.parametrize("method", METHODS)
def test_several_lights_render_the_sum_of_single_light_renders(method, k):
    names = list(SIX)[:k]
    integ = mi.load_dict({"type": method})
    total = integ.render_layers(scene_of(names))
    assert total.stats.get("lights") == k
    total = {n: np.array(v) for n, v in total.items()}
    parts = [layers(integ, scene_of([n])) for n in names]
    for layer in ("full", "scattering", "surface"):
        assert_sum(total, parts, layer)
    np.testing.assert_array_equal(total["distance"], parts[0]["distance"])
    assert all(p["scattering"].max() > 0 for p in parts)       # every light shows


@pytest.mark.parametrize("method", METHODS)
def test_a_partial_render_of_several_lights_equals_the_full_render_there(method):
    scene = scene_of(["light", "light2", "light3"], res=(20, 15))
    integ = mi.load_dict({"type": method})
    full = layers(integ, scene)
    mask = np.random.default_rng(3).random(20 * 15) < 0.3
    part = integ.render_layers(scene, samples=mask)
    computed = np.array(part.samples, dtype=bool)
    assert computed[mask].all()
    for layer in LAYERS:
        a = full[layer].reshape(-1, full[layer].shape[-1])
        b = np.array(part[layer]).reshape(a.shape)
        np.testing.assert_allclose(b[computed], a[computed], rtol=1e-6, atol=1e-7 * a.max())
        assert np.all(b[~computed] == 0), layer


@pytest.mark.parametrize("method", ["epipolar_tree", "minmax_epipolar"])
def test_reused_frames_of_several_lights_equal_full_renders(method):
    """Temporal reuse with two lights: a sample is dirty when a moving
    object's shadow volume from either light meets it; each light keeps its
    own frame state."""
    d = scene_dict(light=None, res=(24, 18))
    d.update({k: SIX[k] for k in ("light", "light2")})
    d["mover"] = {"type": "cube", "bsdf": {"type": "diffuse", "reflectance": 0.6},
                  "to_world": T().translate([-0.7, 0.4, 0.2]).scale(0.25)}
    scene = mi.load_dict(d)
    seq = Sequence(scene, mi.load_dict({"type": method}),
                   [parse_motion("mover:translate=0.6,-0.3,0.2")], frames=3, keep_mask=True)
    reused = 0
    for frame in seq:
        full = layers(mi.load_dict({"type": method}), scene)
        for name in LAYERS:
            np.testing.assert_allclose(frame.layers[name], full[name], rtol=1e-6,
                                       atol=1e-7 * max(1e-30, full[name].max()), err_msg=name)
        reused += frame.recomputed < frame.samples
    assert reused > 0


def test_quality_auto_budgets_the_sum_of_the_lights():
    scene = scene_of(["light", "light2"])
    integ = mi.load_dict({"type": "epipolar_tree", "quality": "auto", "error_budget": 1e-3})
    result = integ.render_layers(scene)
    assert result.stats["auto_predicted_relmse"] > 0
    assert np.array(result["scattering"]).max() > 0


def test_unsupported_emitter_beside_supported_ones_is_named():
    d = scene_dict(res=(8, 6))
    d["sky"] = {"type": "constant", "radiance": 0.1}
    with pytest.raises(ValueError, match="ConstantBackgroundEmitter.*not supported.*volpath"):
        mi.load_dict({"type": "epipolar_tree"}).render_layers(mi.load_dict(d))


def test_several_lights_agree_with_volpath():
    """The exact marcher on a directional, a point and a textured spot light
    at once against volpath max_depth=2 (16 chunks of 1,024 spp, distinct
    seeds), both integrating the pixel footprint: mean within 1 %, relMSE
    after 4x4 blocks within twice volpath's own noise (its chunk variance):
    the several-light sum follows Mitsuba's emitter conventions."""
    assert_agrees_with_volpath(scene_of(list(SIX)[:3], res=(24, 18)))


@pytest.mark.parametrize("method", METHODS)
def test_moving_one_of_several_lights_compiles_nothing(method):
    """An animation moves one light: after the first move (Mitsuba then holds
    the position as a variable instead of the loaded constant: one kernel
    more, once), a new frame compiles nothing -- the lights' constants are
    kernel inputs of their own even where two lights' values coincide (the
    point light's x and the medium's σt are both 0.3 in the second frame,
    the spot's y and the point's 2.5 in the first; the moves are an
    animation's small steps, which change no choice a method makes)."""
    from episcatter.kernels import kernel_log, literal_changes

    scene = scene_of(["light", "light2", "light3"])
    integ = mi.load_dict({"type": method})
    params = mi.traverse(scene)
    logs = []
    for position in ((0.302, 2.5, 0.401), (0.3, 2.499, 0.4)):
        params["light2.position"] = dr.opaque(mi.Point3f, position)    # as an animation sets it
        params.update()
        with kernel_log() as log:
            integ.render_layers(scene, spp=1)
        logs.append(log)
    assert logs[1].compiled == 0, literal_changes(logs[0], logs[1])
