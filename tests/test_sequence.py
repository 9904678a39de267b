"""Sequence: every reused frame equals a full render of that frame (no
periodic refresh), the mask covers every sample whose value changed, and a
moved camera or light recomputes the whole frame."""
import mitsuba as mi
import numpy as np
import pytest

from episcatter.motion import parse_motion
from episcatter.sequence import Sequence
from tests.conftest import scene_dict

T = mi.ScalarTransform4f
MOTIONS = {
    "translate": "mover:translate=0.6,-0.3,0.2",
    "rotate": "mover:rotate=0.2,1,0.4,50",
    "wave": "mover:wave=0.05,0.08,0.0,0.3",
}


def animated_scene(light, res=(24, 18)):
    d = scene_dict(light=light, res=res)
    d["mover"] = {"type": "cube", "bsdf": {"type": "diffuse", "reflectance": 0.6},
                  "to_world": T().translate([-0.7, 0.4, 0.2]).rotate([0, 1, 1], 20).scale(0.25)}
    return mi.load_dict(d)


def raymarch(**props):
    return mi.load_dict({"type": "raymarch", "visibility": "exact", "steps": 32, **props})


def full_render(scene, integ):
    return {k: np.array(v) for k, v in integ.render_layers(scene).items()}


#: every integrator, as the sequence tests make it (raymarch: exact visibility)
METHODS = {"raymarch": {"type": "raymarch", "visibility": "exact", "steps": 32},
           "epipolar_tree": {"type": "epipolar_tree"},
           "fourier_filter": {"type": "fourier_filter"},
           "minmax_epipolar": {"type": "minmax_epipolar"}}
#: methods that reuse at a finer grain than the whole frame (every one)
PARTIAL = tuple(METHODS)


@pytest.mark.slow
@pytest.mark.parametrize("motion", sorted(MOTIONS))
@pytest.mark.parametrize("light", ["directional", "point", "spot"])
@pytest.mark.parametrize("method", sorted(METHODS))
def test_reused_frames_equal_full_renders(method, light, motion):
    """Every frame of a reused sequence equals a full render of that frame,
    and its recomputed samples contain every sample whose value changed."""
    scene = animated_scene(light)
    seq = Sequence(scene, mi.load_dict(METHODS[method]), [parse_motion(MOTIONS[motion])],
                   frames=4, keep_mask=True)
    previous, reused = None, 0
    for frame in seq:
        full = full_render(scene, mi.load_dict(METHODS[method]))
        for name in ("full", "scattering", "surface", "distance"):
            np.testing.assert_allclose(frame.layers[name], full[name], rtol=1e-6,
                                       atol=1e-7 * max(1e-30, full[name].max()), err_msg=name)
        if previous is not None:
            changed = np.any(full["scattering"] != previous["scattering"], axis=2).ravel()
            changed |= np.any(full["distance"] != previous["distance"], axis=2).ravel()
            missed = np.count_nonzero(changed & ~frame.mask)
            print(f"{method} {light}/{motion} frame {frame.index}: recomputed "
                  f"{frame.recomputed}/{frame.samples}, changed {changed.sum()}, missed {missed}"
                  f" {frame.whole_frame or ''}")
            assert frame.whole_frame in ([], ["frame choices"])
            assert missed == 0
            assert changed.sum() > 0                  # the object moved something
            reused += frame.recomputed < frame.samples
        else:
            assert frame.whole_frame == ["camera", "light", "medium"]
            assert frame.recomputed == frame.samples
        previous = full
    if method in PARTIAL:
        assert reused > 0                             # reuse happened


@pytest.mark.parametrize("light", ["directional", "point"])
@pytest.mark.parametrize("method", ["fourier_filter", "minmax_epipolar"])
def test_a_small_mover_recomputes_a_small_part(method, light):
    """Per-row (fourier_filter) and per-slice (minmax_epipolar) reuse: a
    small object moving in a corner recomputes well under the whole frame,
    and the reused frame still equals its full render."""
    d = scene_dict(light=light, res=(48, 36))
    d["mover"] = {"type": "cube", "bsdf": {"type": "diffuse", "reflectance": 0.6},
                  "to_world": T().translate([-1.2, 0.9, 0.6]).scale(0.08)}
    scene = mi.load_dict(d)
    seq = Sequence(scene, mi.load_dict(METHODS[method]),
                   [parse_motion("mover:translate=0.1,-0.05,0")], frames=3)
    for frame in seq:
        full = full_render(scene, mi.load_dict(METHODS[method]))
        np.testing.assert_allclose(frame.layers["full"], full["full"], rtol=1e-6,
                                   atol=1e-7 * full["full"].max())
        if frame.index:
            print(f"{method} {light} frame {frame.index}: {frame.recomputed_fraction:.3f}")
            assert frame.whole_frame == [] and frame.recomputed_fraction < 0.5


@pytest.mark.parametrize("what", ["light", "camera"])
def test_moving_light_or_camera_recomputes_the_whole_frame(what):
    scene = animated_scene("point")
    seq = Sequence(scene, raymarch(), [parse_motion(MOTIONS["translate"])], frames=3)
    params = mi.traverse(scene)
    for k in range(3):
        if k == 2:
            if what == "light":
                params["light.position"] = [0.2, 2.1, 0.4]
            else:
                params["sensor.to_world"] = T().look_at(origin=[0.1, 0.5, 3], target=[0, 0, 0],
                                                        up=[0, 1, 0])
            params.update()
        frame = seq.render_frame(k)
        if k == 1:
            assert frame.recomputed < frame.samples
        full = full_render(scene, raymarch())
        np.testing.assert_allclose(frame.layers["full"], full["full"], rtol=1e-6, atol=1e-9)
    assert frame.whole_frame == [what]
    assert frame.recomputed == frame.samples


def test_hybrid_march_reuse_is_exact():
    scene = animated_scene("directional")
    seq = Sequence(scene, raymarch(march="hybrid"), [parse_motion(MOTIONS["rotate"])], frames=3)
    for frame in seq:
        full = full_render(scene, raymarch(march="hybrid"))
        np.testing.assert_allclose(frame.layers["full"], full["full"], rtol=1e-6, atol=1e-9)


def test_reuse_refuses_what_it_cannot_make_exact():
    scene = animated_scene("directional")
    props = {"type": "raymarch"}                    # a shadow map fitted to the whole frame
    with pytest.raises(ValueError, match="visibility='exact'"):
        Sequence(scene, mi.load_dict(props), [parse_motion(MOTIONS["translate"])], frames=2)
    Sequence(scene, mi.load_dict(props), [parse_motion(MOTIONS["translate"])], frames=2, reuse=False)
    tree = {"type": "epipolar_tree", "blockers": "resampled"}
    with pytest.raises(ValueError, match="blockers='traced'"):
        Sequence(scene, mi.load_dict(tree), [parse_motion(MOTIONS["translate"])], frames=2)


def test_a_static_frame_recomputes_nothing():
    d = scene_dict(res=(16, 12))
    d["mover"] = {"type": "cube", "to_world": T().scale(0.2), "bsdf": {"type": "diffuse"}}
    scene = mi.load_dict(d)
    seq = Sequence(scene, raymarch(steps=16), [parse_motion("mover:translate=0,0,0")], frames=3)
    frames = list(seq)
    assert [f.recomputed for f in frames[1:]] != [0, 0]   # the object's own volume is dirty
    far = Sequence(mi.load_dict({**d, "mover": {**d["mover"], "to_world": T().translate([0, 0, -3.9]).scale(0.01)}}),
                   raymarch(steps=16), [parse_motion("mover:translate=0,0,0")], frames=2)
    a, b = list(far)
    np.testing.assert_array_equal(a.layers["full"], b.layers["full"])


@pytest.mark.parametrize("text, match", [("mover", "SHAPE_ID:kind"), ("mover:spin=1", "unknown"),
                                         ("mover:translate=1,2", "needs 3"),
                                         ("ghost:translate=1,2,3", "not in the scene"),
                                         ("blocker:wave=0.1,0,0,1", "only meshes deform")])
def test_bad_motions_name_the_fix(text, match):
    with pytest.raises(ValueError, match=match):
        Sequence(animated_scene("directional"), raymarch(), [parse_motion(text)], frames=2)


def test_sphere_moves_by_its_transform():
    scene = animated_scene("directional")
    seq = Sequence(scene, raymarch(), [parse_motion("blocker:translate=0.3,0,0")], frames=2)
    frames = list(seq)
    full = full_render(scene, raymarch())
    np.testing.assert_allclose(frames[1].layers["full"], full["full"], rtol=1e-6, atol=1e-9)
    assert 0 < frames[1].recomputed < frames[1].samples
