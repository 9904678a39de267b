"""Every unsupported or invalid input raises ValueError naming the problem."""
import math

import mitsuba as mi
import numpy as np
import pytest

from integrators.core.scene_params import SceneParams
from tests.conftest import LIGHTS, T, scene_dict


def params_of(**kw):
    return SceneParams.from_scene(mi.load_dict(scene_dict(**kw)))


def test_reads_directional_scene():
    p = params_of()
    assert p.light.kind == "directional"
    d = np.array([0.3, -1, -0.2])
    np.testing.assert_allclose(p.light.direction, -d / np.linalg.norm(d), atol=1e-6)
    np.testing.assert_allclose(p.medium.sigma_t, 0.3, rtol=1e-6)
    np.testing.assert_allclose(p.medium.sigma_s, 0.24, rtol=1e-6)
    np.testing.assert_allclose(p.medium.bounds_min, -4)
    assert p.medium.phase_kind == "isotropic"


@pytest.mark.parametrize("light", ["spot_textured", "point"])
def test_reads_local_lights(light):
    p = params_of(light=light)
    assert p.light.kind == light.split("_")[0]
    assert p.light.position is not None
    if light == "spot_textured":
        assert p.light.textured and p.light.cutoff_angle == pytest.approx(35)


def test_reads_several_lights_one_at_a_time():
    """Several emitters: every one read, each alone in its per-light params;
    asking the several-light params for 'the' light is an error."""
    p = params_of(light2=LIGHTS["point"])
    assert [l.kind for l in p.lights] == ["directional", "point"]
    with pytest.raises(RuntimeError, match="per_light"):
        p.light
    one = p.per_light()
    assert [q.light.kind for q in one] == ["directional", "point"]
    assert all(q.camera is p.camera and q.medium is p.medium for q in one)
    assert params_of().per_light()[0].light.kind == "directional"


def test_plain_spot_is_not_textured():
    assert not params_of(light="spot").light.textured


@pytest.mark.parametrize("phase,kind", [
    ({"type": "hg", "g": 0.5}, "hg"), ({"type": "rayleigh"}, "rayleigh"),
    ({"type": "blendphase", "weight": 0.3, "phase1": {"type": "hg", "g": -0.5},
      "phase2": {"type": "isotropic"}}, "blendphase")])
def test_supported_phases(phase, kind):
    assert params_of(phase=phase).medium.phase_kind == kind


def no_medium_sensor():
    d = scene_dict()
    del d["sensor"]["medium"]
    return d


def bad(**kw):
    return lambda: scene_dict(**kw)


CASES = {
    "no medium on the sensor": (no_medium_sensor, "the sensor has no medium"),
    "heterogeneous medium": (bad(medium={
        "type": "heterogeneous", "id": "medium",
        "sigma_t": {"type": "constvolume", "value": 0.3}}), "not supported"),
    "area light": (bad(light=None, arealight={
        "type": "rectangle", "to_world": T().translate([0, 2, 0]),
        "emitter": {"type": "area", "radiance": 1.0}}), "not supported"),
    "environment map": (bad(light={"type": "constant", "radiance": 1.0}), "not supported"),
    "a light beside an environment": (bad(light2={"type": "constant", "radiance": 1.0}),
                                      "ConstantBackgroundEmitter.*not supported"),
    "no light": (bad(light=None), "no emitter"),
    "orthographic camera": (lambda: {**scene_dict(), "sensor": {
        **{k: v for k, v in scene_dict()["sensor"].items() if k != "fov"},
        "type": "orthographic"}}, "perspective"),
    "thin lens camera": (lambda: {**scene_dict(), "sensor": {
        **scene_dict()["sensor"], "type": "thinlens", "aperture_radius": 0.1,
        "focus_distance": 2.0}}, "perspective"),
    "NaN sigma_t": (bad(sigma_t=math.nan), "sigma_t"),
    "negative sigma_t": (bad(sigma_t=-0.1), "negative"),
    "albedo above one": (bad(albedo=1.5), "albedo"),
    "negative irradiance": (bad(light={"type": "directional", "direction": [0, -1, 0],
                                       "irradiance": -1.0}), "negative"),
    "NaN intensity": (bad(light={"type": "point", "position": [0, 1, 0],
                                 "intensity": math.nan}), "not finite"),
    "no boundary": (bad(box=None), "no boundary"),
    "boundary not null": (bad(box={"type": "cube", "to_world": T().scale(4),
                                   "bsdf": {"type": "diffuse"},
                                   "interior": {"type": "ref", "id": "medium"}}), "null"),
    "boundary not closed": (bad(box={"type": "rectangle", "to_world": T().scale(4),
                                     "bsdf": {"type": "null"},
                                     "interior": {"type": "ref", "id": "medium"}}),
                            "degenerate bounding box"),
    "boundary a cylinder": (bad(box={"type": "cylinder", "radius": 4, "p0": [0, -4, 0],
                                     "p1": [0, 4, 0], "bsdf": {"type": "null"},
                                     "interior": {"type": "ref", "id": "medium"}}),
                            "Cylinder, not a box, a sphere or a closed convex mesh"),
    "camera outside the medium": (bad(box_scale=2.0), "outside the boundary of the medium"),
    "HG g out of range": (bad(phase={"type": "hg", "g": math.nan}), "g"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_raises_named_error(case):
    make, needle = CASES[case]
    scene = mi.load_dict(make())
    with pytest.raises(ValueError, match=needle):
        SceneParams.from_scene(scene)


def test_render_error_reaches_user_through_mi_render():
    """mi.render wraps our ValueError; the CLI unwraps it (see episcatter.cli)."""
    from episcatter.cli import user_error
    scene = mi.load_dict(scene_dict(albedo=1.5))
    integ = mi.load_dict({"type": "raymarch"})
    with pytest.raises(RuntimeError) as info:
        mi.render(scene, integrator=integ)
    err = user_error(info.value)
    assert isinstance(err, ValueError) and "albedo" in str(err)


@pytest.mark.parametrize("props,needle", [
    ({"steps": 0}, "steps"), ({"steps": 2.5}, "integer"), ({"visibility": "magic"}, "visibility"),
    ({"output": "nope"}, "output"), ({"shadowmap_resolution": -4}, "shadowmap_resolution")])
def test_bad_integrator_properties(props, needle):
    with pytest.raises(Exception, match=needle):
        mi.load_dict({"type": "raymarch", **props})
