"""Partial renders (the template's ``samples`` mask): only the (widened)
samples are computed, they equal the full render's (to float rounding), the
others are 0, and ``RenderResult.samples`` says which were computed."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from integrators.core.capture import capture_camera
from integrators.core.scene_params import SceneParams
from tests.conftest import scene_dict

RES = (20, 15)
CASES = [("raymarch", {"steps": 64, "shadowmap_resolution": 256}, 1),
         ("raymarch", {"visibility": "exact", "steps": 32, "jitter": True}, 2),
         ("epipolar_tree", {}, 1), ("fourier_filter", {}, 1)]


def mask_of(n: int, fraction: float, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).random(n) < fraction


@pytest.mark.parametrize("light", ["directional", "spot"])
@pytest.mark.parametrize("kind,props,spp", CASES, ids=lambda v: str(v))
def test_masked_render_equals_full_render_on_computed_samples(kind, props, spp, light):
    scene = mi.load_dict(scene_dict(light=light, res=RES))
    integ = mi.load_dict({"type": kind, **props})
    full = integ.render_layers(scene, spp=spp)
    n = RES[0] * RES[1] * spp
    part = integ.render_layers(scene, spp=spp, samples=mask_of(n, 0.3))
    computed = np.array(part.samples, dtype=bool)
    assert computed.shape == (n,) and computed[mask_of(n, 0.3)].all()
    if kind == "raymarch":                      # per-sample: exactly the mask
        assert np.array_equal(computed, mask_of(n, 0.3))
    per_pixel = computed.reshape(-1, spp)
    whole, none = per_pixel.all(axis=1), ~per_pixel.any(axis=1)
    for layer in ("full", "scattering", "surface", "distance"):
        a = np.array(full[layer]).reshape(-1, np.array(full[layer]).shape[-1])
        b = np.array(part[layer]).reshape(a.shape)
        np.testing.assert_allclose(b[whole], a[whole], rtol=1e-6, atol=1e-7 * a.max())
        assert np.all(b[none] == 0), layer


@pytest.mark.parametrize("kind", ["raymarch", "epipolar_tree", "fourier_filter"])
def test_empty_mask_computes_nothing(kind):
    scene = mi.load_dict(scene_dict(res=(8, 6)))
    part = mi.load_dict({"type": kind}).render_layers(scene, samples=np.zeros(48, bool))
    assert not np.any(np.array(part.samples)) and not np.any(np.array(part["full"]))


def test_bad_masks_name_the_fix():
    scene = mi.load_dict(scene_dict(res=(8, 6)))
    integ = mi.load_dict({"type": "raymarch", "steps": 4})
    with pytest.raises(ValueError, match="48 camera samples"):
        integ.render_layers(scene, samples=np.ones(47, bool))
    with pytest.raises(ValueError, match="boolean mask"):
        integ.render_layers(scene, samples=np.ones(48))


def test_render_state_lives_in_the_result():
    """Nothing about a render is kept on the integrator: two renders'
    results keep their own timings and stats."""
    scene = mi.load_dict(scene_dict(res=(8, 6)))
    integ = mi.load_dict({"type": "epipolar_tree"})
    a = integ.render_layers(scene)
    b = integ.render_layers(scene, samples=np.zeros(48, bool))
    assert "sweep" in a.timings and a.stats["query_count"] > 0 and "query_count" not in b.stats
    for name in ("timings", "render_seed", "last_interval_traced", "query_count",
                 "rectification_used"):
        assert not hasattr(integ, name), name
    integ.record(x=1)                      # outside a render: a detached record
    assert "x" not in integ.render_layers(scene).stats


def test_subset_capture_equals_the_full_capture_there():
    params = SceneParams.from_scene(mi.load_dict(scene_dict(res=(12, 9))))
    full = capture_camera(params, spp=4, jitter=True, seed=3)
    idx = mi.UInt32(np.array([0, 5, 17, 100, 431], dtype=np.uint32))
    part = capture_camera(params, spp=4, jitter=True, seed=3, samples=idx)
    for name in ("pixel", "o", "omega", "d", "T_cam", "L_surface", "hit"):
        a, b = getattr(full, name), getattr(part, name)
        np.testing.assert_array_equal(np.array(dr.gather(type(a), a, idx)), np.array(b), err_msg=name)


def test_per_sample_methods_capture_the_masked_samples_alone():
    """raymarch with exact visibility: the partial render's capture holds
    the masked samples alone, with their full-render values."""
    scene = mi.load_dict(scene_dict(res=(12, 9)))
    integ = mi.load_dict({"type": "raymarch", "visibility": "exact", "steps": 16})
    mask = mask_of(108, 0.3)
    full = integ.render_layers(scene)
    part = integ.render_layers(scene, samples=mask)
    assert part.capture.count == mask.sum()
    np.testing.assert_array_equal(np.array(part.capture.sample), np.flatnonzero(mask))
    np.testing.assert_allclose(np.array(part.L_scat),
                               np.array(full.L_scat)[:, mask], rtol=1e-6, atol=1e-9)


def test_a_known_capture_is_completed_by_the_masked_samples():
    """``known=``: only the masked samples are captured anew; the rest come
    from the given capture (an animation's last frame)."""
    scene = mi.load_dict(scene_dict(res=(16, 12)))
    integ = mi.load_dict({"type": "epipolar_tree"})
    full = integ.render_layers(scene)
    mask = mask_of(192, 0.1)
    part = integ.render_layers(scene, samples=mask, known=full.capture)
    computed = np.array(part.samples, dtype=bool)
    np.testing.assert_array_equal(np.array(part.capture.d), np.array(full.capture.d))
    np.testing.assert_allclose(np.array(part.L_scat)[:, computed],
                               np.array(full.L_scat)[:, computed], rtol=1e-6, atol=1e-9)
    with pytest.raises(ValueError, match="samples= mask"):
        integ.render_layers(scene, known=full.capture)
