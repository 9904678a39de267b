"""raymarch march=hybrid (Wyman & Ramsey 2008) equals march=full with exact
visibility: the bounded shadow volumes are conservative."""
import mitsuba as mi
import numpy as np
import pytest

from integrators.core.capture import capture_camera
from integrators.core.hybrid_march import shadow_range
from integrators.core.scene_params import SceneParams
from tests.conftest import scene_dict

T = mi.ScalarTransform4f


def render(scene, **props):
    integ = mi.load_dict({"type": "raymarch", "visibility": "exact", "steps": 48, **props})
    result = integ.render_layers(scene, spp=1)
    return np.array(result["scattering"]), result


@pytest.mark.parametrize("light", ["directional", "point", "spot"])
def test_hybrid_equals_full_march(light):
    d = scene_dict(light=light, res=(40, 30))
    d["cube"] = {"type": "cube", "bsdf": {"type": "diffuse"},
                 "to_world": T().translate([-0.8, 0.2, 0.3]).rotate([0, 1, 1], 30).scale(0.3)}
    scene = mi.load_dict(d)
    full, _ = render(scene)
    hybrid, integ = render(scene, march="hybrid", volume_boxes=4)
    assert "shadow_volumes" in integ.timings
    assert full.max() > 0
    np.testing.assert_allclose(hybrid, full, rtol=1e-5, atol=1e-7 * full.max())
    # the volumes leave part of the rays lit (the test is not vacuous)
    params = SceneParams.from_scene(scene)
    cap = capture_camera(params)
    lo, hi = (np.array(v) for v in shadow_range(params, cap, 4))
    d = np.array(cap.d)
    marched = np.clip(np.minimum(hi, d) - np.maximum(lo, 0), 0, None).sum() / d.sum()
    print(f"{light}: fraction of the camera segments marched with visibility {marched:.3f}")
    assert marched < 0.9


def test_hybrid_needs_exact_visibility():
    with pytest.raises((ValueError, RuntimeError), match="visibility=.exact."):
        mi.load_dict({"type": "raymarch", "march": "hybrid"})
