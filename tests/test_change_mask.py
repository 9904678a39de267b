"""change_mask: Cyrus–Beck clipping against extruded boxes vs the dense
NumPy oracle, nasty cases included; whole-frame change detection."""
import mitsuba as mi
import numpy as np
import pytest

from integrators.core.shadow_volumes import (Boxes, ShadowVolumes, clip_segments,
                                             in_shadow_volume_reference, shadow_volume_planes,
                                             triangle_cluster_boxes)
from integrators.partial.change_mask import (change_mask_reference, frame_invariants,
                                             whole_frame_changes)
from integrators.core.scene_params import LightParams, SceneParams
from tests.conftest import scene_dict

LIGHTS = {
    "directional": LightParams("directional", np.ones(3), direction=np.array([0.3, 1.0, -0.2]) / np.linalg.norm([0.3, 1.0, -0.2])),
    "axis_directional": LightParams("directional", np.ones(3), direction=np.array([0.0, 1.0, 0.0])),
    "point": LightParams("point", np.ones(3), position=np.array([0.4, 2.5, 0.3])),
    "point_in_plane": LightParams("point", np.ones(3), position=np.array([0.5, 2.5, 0.0])),
}


class _Params:
    """The two fields ShadowVolumes.from_boxes reads."""
    def __init__(self, light):
        self.light = light
        self.scene_extent = 10.0


def random_segments(rng, n):
    o = rng.uniform(-3, 3, (n, 3))
    w = rng.normal(size=(n, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    d = rng.uniform(0.0, 6.0, n)
    d[:5] = 0.0   # zero-length segments
    return o, w, d


def fast_clip(boxes, light, o, w, d, pad=0.0):
    vols = ShadowVolumes.from_boxes(boxes, _Params(light), pad=pad)
    hit, lo, hi = clip_segments(vols, mi.Point3f(*o.T.astype(np.float32)),
                                mi.Vector3f(*w.T.astype(np.float32)), mi.Float(d.astype(np.float32)))
    return np.array(hit), np.array(lo), np.array(hi)


BOXES = Boxes(np.array([[-0.5, 0.0, -0.4], [1.0, -1.0, 1.0], [-2.0, 0.5, -2.0]]),
              np.array([[0.5, 0.6, 0.4], [1.5, -0.2, 1.3], [-1.0, 0.5, -1.5]]))  # last one flat


@pytest.mark.parametrize("light", sorted(LIGHTS))
def test_clip_matches_dense_oracle(light):
    rng = np.random.default_rng(1)
    o, w, d = random_segments(rng, 2000)
    L = LIGHTS[light]
    pad = 1e-3
    hit, lo, hi = fast_clip(BOXES, L, o, w, d, pad=pad / 10.0)   # pad * extent(10)
    inner = change_mask_reference(o, w, d, BOXES, L, samples=400)
    outer = change_mask_reference(o, w, d, BOXES.padded(0.02), L, samples=400)
    missed = np.count_nonzero(inner & ~hit)
    extra = np.count_nonzero(hit & ~outer)
    print(f"{light}: fast {hit.sum()}, oracle {inner.sum()}, missed {missed}, "
          f"beyond the 0.02-padded oracle {extra}")
    assert missed == 0
    assert extra <= 0.01 * max(1, inner.sum())
    assert 0.05 * len(d) < inner.sum() < 0.95 * len(d)   # the test means something
    # the hull [lo, hi] holds every sampled point inside a volume
    t = np.linspace(0, 1, 400)
    for i in np.flatnonzero(inner)[:300]:
        x = o[i] + w[i] * (d[i] * t)[:, None]
        ts = d[i] * t[in_shadow_volume_reference(x, BOXES, L)]
        assert lo[i] - 1e-4 <= ts.min() and ts.max() <= hi[i] + 1e-4


def test_light_inside_box_makes_everything_dirty():
    L = LightParams("point", np.ones(3), position=np.array([0.0, 0.3, 0.0]))
    rng = np.random.default_rng(2)
    o, w, d = random_segments(rng, 500)
    hit, lo, hi = fast_clip(BOXES, L, o, w, d)
    assert hit.all()
    np.testing.assert_array_equal(lo, 0.0)
    np.testing.assert_allclose(hi, d.astype(np.float32))


def test_planes_bound_exactly_the_oracle_volume():
    """Points inside every plane <=> the oracle's slab test (away from the
    boundary), for each light kind."""
    rng = np.random.default_rng(3)
    x = rng.uniform(-4, 4, (20000, 3))
    for name, L in LIGHTS.items():
        planes = shadow_volume_planes(BOXES, L)
        inside = np.zeros(len(x), bool)
        margin = np.full(len(x), np.inf)
        for P in planes:
            s = x @ P[:, :3].T - P[:, 3]
            inside |= np.all(s <= 0, axis=1)
            margin = np.minimum(margin, np.abs(s).min(1))
        ref = in_shadow_volume_reference(x, BOXES, L)
        clear = margin > 1e-6
        assert np.array_equal(inside[clear], ref[clear]), name


def test_cluster_boxes_cover_every_triangle():
    rng = np.random.default_rng(4)
    v = rng.normal(size=(300, 3))
    f = rng.integers(0, 300, (500, 3))
    b = triangle_cluster_boxes(v, f, 16)
    assert len(b) == 16
    tri = v[f]
    covered = np.zeros(len(f), bool)
    for lo, hi in zip(b.lo, b.hi):
        covered |= np.all((tri >= lo - 1e-12) & (tri <= hi + 1e-12), axis=(1, 2))
    assert covered.all()


def test_whole_frame_changes_are_detected():
    scene = mi.load_dict(scene_dict(res=(8, 6)))
    a = frame_invariants(SceneParams.from_scene(scene))
    assert whole_frame_changes(None, a) == ["camera", "light", "medium"]
    assert whole_frame_changes(a, frame_invariants(SceneParams.from_scene(scene))) == []
    p = mi.traverse(scene)
    p["light.irradiance.value"] = mi.Color3f(3.0)
    p.update()
    b = frame_invariants(SceneParams.from_scene(scene))
    assert whole_frame_changes(a, b) == ["light"]
    p["sensor.to_world"] = mi.ScalarTransform4f().look_at(origin=[0, 0.6, 3], target=[0, 0, 0], up=[0, 1, 0])
    p["medium.sigma_t.value.value"] = 0.5
    p.update()
    c = frame_invariants(SceneParams.from_scene(scene))
    assert whole_frame_changes(b, c) == ["camera", "medium"]


@pytest.mark.parametrize("light", ["directional", "point"])
def test_hulls_only_prune(light):
    """Sets of boxes behind their hull volume clip exactly like the boxes
    alone; first_hit gives the same hits."""
    rng = np.random.default_rng(5)
    o, w, d = random_segments(rng, 3000)
    L = LIGHTS[light]
    sets = [triangle_cluster_boxes(rng.normal(size=(60, 3)) * 0.4 + ctr, rng.integers(0, 60, (80, 3)), 6)
            for ctr in ([-1.0, 0.2, 0.0], [1.2, -0.5, 0.8])] + [BOXES]
    flat = Boxes.concat(sets)
    args = (mi.Point3f(*o.T.astype(np.float32)), mi.Vector3f(*w.T.astype(np.float32)),
            mi.Float(d.astype(np.float32)))
    a = [np.array(v) for v in clip_segments(ShadowVolumes.from_boxes(flat, _Params(L)), *args)]
    grouped = ShadowVolumes.from_sets(sets, _Params(L))
    assert grouped.count == len(flat) + 3   # a hull per set
    b = [np.array(v) for v in clip_segments(grouped, *args)]
    first = np.array(clip_segments(grouped, *args, first_hit=True)[0])
    print(f"{light}: {a[0].sum()} of {len(d)} segments meet a volume")
    assert 0 < a[0].sum() < len(d)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(first, a[0])


@pytest.mark.parametrize("light", ["directional", "point", "spot"])
def test_volume_bounds_hold_the_volumes_and_the_cull_changes_nothing(light):
    """Every point of the medium box inside a shadow volume (the NumPy
    oracle) lies in ``volume_bounds``, and clipping only the segments that
    meet the bounds gives the mask of clipping all of them."""
    from dataclasses import replace

    from integrators.core.capture import capture_camera
    from integrators.partial.change_mask import change_mask
    from integrators.core.shadow_volumes import in_shadow_volume_reference, volume_bounds
    params = SceneParams.from_scene(mi.load_dict(scene_dict(light=light, res=(32, 24))))
    boxes = Boxes(np.array([[-0.6, 0.1, -0.3], [0.5, -0.4, 0.6]]),
                  np.array([[-0.3, 0.4, 0.1], [0.8, -0.2, 0.9]]))
    lo, hi = volume_bounds(boxes, params)
    rng = np.random.default_rng(5)
    m_lo, m_hi = np.asarray(params.medium.bounds_min), np.asarray(params.medium.bounds_max)
    x = rng.uniform(m_lo, m_hi, (200_000, 3))
    inside = in_shadow_volume_reference(x, boxes, params.light)
    assert inside.sum() > 100
    assert np.all((x[inside] >= lo - 1e-9) & (x[inside] <= hi + 1e-9))
    cap = capture_camera(params)
    vols = ShadowVolumes.from_sets([boxes], params)
    culled = np.array(change_mask(cap, vols))
    print(f"{light}: {culled.sum()} dirty of {culled.size}")
    np.testing.assert_array_equal(culled, np.array(change_mask(cap, replace(vols, bounds=None))))
