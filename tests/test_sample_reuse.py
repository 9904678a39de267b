"""Partial captures and renders: a subset capture has each sample's value
from the full capture; an empty mask recomputes nothing."""
import drjit as dr
import mitsuba as mi
import numpy as np

from episcatter.motion import parse_motion
from episcatter.sequence import Sequence
from integrators.capture import capture_camera
from integrators.scene_params import SceneParams
from tests.conftest import scene_dict


def test_subset_capture_equals_the_full_capture_there():
    params = SceneParams.from_scene(mi.load_dict(scene_dict(res=(12, 9))))
    full = capture_camera(params, spp=4, jitter=True, seed=3)
    idx = mi.UInt32(np.array([0, 5, 17, 100, 431], dtype=np.uint32))
    part = capture_camera(params, spp=4, jitter=True, seed=3, samples=idx)
    for name in ("pixel", "o", "omega", "d", "T_cam", "L_surface", "hit"):
        a, b = getattr(full, name), getattr(part, name)
        np.testing.assert_array_equal(np.array(dr.gather(type(a), a, idx)), np.array(b), err_msg=name)


def test_a_static_frame_recomputes_nothing():
    d = scene_dict(res=(16, 12))
    d["mover"] = {"type": "cube", "to_world": mi.ScalarTransform4f().scale(0.2),
                  "bsdf": {"type": "diffuse"}}
    scene = mi.load_dict(d)
    integ = mi.load_dict({"type": "raymarch", "visibility": "exact", "steps": 16})
    seq = Sequence(scene, integ, [parse_motion("mover:translate=0,0,0")], frames=3)
    frames = list(seq)
    assert [f.recomputed for f in frames[1:]] != [0, 0]   # the object's own volume is dirty
    far = Sequence(mi.load_dict({**d, "mover": {**d["mover"], "to_world": mi.ScalarTransform4f().translate([0, 0, -3.9]).scale(0.01)}}),
                   integ, [parse_motion("mover:translate=0,0,0")], frames=2)
    a, b = list(far)
    np.testing.assert_array_equal(a.layers["full"], b.layers["full"])
