"""Fog volumes bounded by any convex boundary Mitsuba users write: a
``cube`` with any ``to_world`` (rotated, scaled, sheared) or a ``sphere``.

Oracles: a NumPy twin of the ray-boundary interval on random rays (misses,
grazing and degenerate directions included); ``volpath`` (``max_depth=2``)
within its noise for the exact marcher; the exact marcher for every other
integrator."""
from __future__ import annotations

import warnings

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from episcatter.metrics import scale_free_relmse
from integrators.core.light_transport import medium_interval
from integrators.core.scene_params import SceneParams, _box_frame
from tests.conftest import T, scene_dict
from tests.oracles import assert_agrees_with_volpath


METHODS = ["raymarch", "epipolar_tree", "fourier_filter", "minmax_epipolar"]
INTERIOR = {"bsdf": {"type": "null"}, "interior": {"type": "ref", "id": "medium"}}
#: boundaries that clip the visible fog and the shafts (the camera at (0, 0.5, 3) inside)
BOUNDARIES = {
    "rotated box": {"type": "cube", **INTERIOR, "to_world": T().translate([0, 0.4, 1.2])
                    .rotate([0.3, 1, 0.2], 35).scale([1.6, 1.2, 2.2])},
    "sheared box": {"type": "cube", **INTERIOR, "to_world": mi.ScalarTransform4f(np.array(
        [[1.8, 0.5, 0.0, 0.1], [0.0, 1.5, 0.4, 0.3], [0.3, 0.0, 2.4, 1.0], [0, 0, 0, 1]]))},
    "sphere": {"type": "sphere", **INTERIOR, "center": [0, 0.3, 1.0], "radius": 2.2},
}


def scene_with(boundary, light="directional", res=(32, 24), **kw):
    return mi.load_dict(scene_dict(light=light, res=res, box=BOUNDARIES[boundary], **kw))


def interval_reference(to_local, kind, p, d):
    """NumPy (float64): the line p + t d in the shape's frame against the
    cube [-1, 1]^3 (slabs) or the unit sphere (quadratic); (inf, -inf) on a miss."""
    A, b = to_local[:, :3], to_local[:, 3]
    pl, dl = p @ A.T + b, d @ A.T
    if kind == "box":
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = (-1 - pl) / dl, (1 - pl) / dl
        lo = np.where(dl == 0, np.where(np.abs(pl) <= 1, -np.inf, np.inf), np.minimum(t0, t1))
        hi = np.where(dl == 0, np.where(np.abs(pl) <= 1, np.inf, -np.inf), np.maximum(t0, t1))
        return lo.max(1), hi.min(1)
    a, h, c = (dl * dl).sum(1), (pl * dl).sum(1), (pl * pl).sum(1) - 1
    disc = h * h - a * c
    r = np.sqrt(np.maximum(disc, 0))
    return (np.where(disc >= 0, (-h - r) / a, np.inf), np.where(disc >= 0, (-h + r) / a, -np.inf))


@pytest.mark.parametrize("boundary", sorted(BOUNDARIES))
def test_medium_interval_matches_its_numpy_twin(boundary):
    params = SceneParams.from_scene(scene_with(boundary))
    med = params.medium
    rng = np.random.default_rng(7)
    n = 4000
    p = rng.uniform(-5, 5, (n, 3))
    d = rng.normal(size=(n, 3))
    d[:200, 1] = 0.0                                  # directions in a coordinate plane
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    near, far = medium_interval(params, mi.Point3f(*p.T.astype(np.float32)),
                                mi.Vector3f(*d.T.astype(np.float32)))
    near, far = np.array(near, np.float64), np.array(far, np.float64)
    ref_near, ref_far = interval_reference(med.to_local, med.boundary, p, d)
    hit = ref_far > np.maximum(ref_near, -1e30) + 1e-3
    clear_miss = ref_far < ref_near - 1e-3
    assert hit.sum() > 500 and clear_miss.sum() > 500
    np.testing.assert_allclose(near[hit], ref_near[hit], atol=2e-4)
    np.testing.assert_allclose(far[hit], ref_far[hit], atol=2e-4)
    assert np.all(far[clear_miss] < near[clear_miss])
    assert np.all(np.isfinite(near) & np.isfinite(far))     # differences stay finite


def test_box_frames_are_found_and_other_meshes_are_not():
    M = np.array([[1.8, 0.5, 0.0, 0.1], [0.0, 1.5, 0.4, 0.3], [0.3, 0.0, 2.4, 1.0]])
    cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    world = cube @ M[:, :3].T + M[:, 3]
    to_local = _box_frame(np.repeat(world, 3, axis=0), 1e-6)
    np.testing.assert_allclose(np.abs(world @ to_local[:, :3].T + to_local[:, 3]), 1.0,
                               atol=1e-9)
    octahedron = np.concatenate([np.eye(3), -np.eye(3)])
    assert _box_frame(octahedron, 1e-6) is None
    assert _box_frame(np.concatenate([world, [[5.0, 5.0, 5.0]]]), 1e-6) is None


@pytest.mark.parametrize("boundary", ["rotated box", "sphere"])
@pytest.mark.parametrize("light", ["directional", "point"])
def test_exact_marcher_agrees_with_volpath_in_any_boundary(boundary, light):
    assert_agrees_with_volpath(scene_with(boundary, light, res=(24, 18)))


@pytest.mark.parametrize("light", ["directional", "point", "spot"])
@pytest.mark.parametrize("boundary", sorted(BOUNDARIES))
@pytest.mark.parametrize("method", METHODS)
def test_every_integrator_in_any_boundary(method, boundary, light):
    assert_matches_the_exact_marcher(scene_with(boundary, light), method)


def assert_matches_the_exact_marcher(scene, method):
    """``method`` at its defaults against the exact marcher (1,024 steps,
    pixel centres): finite, relMSE < 1e-4, the fog lit."""
    ref = np.array(mi.load_dict({"type": "raymarch", "visibility": "exact", "steps": 1024})
                   .render_layers(scene, spp=1)["scattering"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        img = np.array(mi.load_dict({"type": method}).render_layers(scene, spp=1)["scattering"])
    assert ref.max() > 0 and np.all(np.isfinite(img))
    assert scale_free_relmse(img, ref) < 1e-4


def test_the_boundary_clips_the_fog():
    """The same scene in a sphere and in its bounding box differ (shorter
    view and light paths in the sphere): the boundary, not its bounding
    box, bounds the fog."""
    sphere = scene_with("sphere")
    lo, hi = (SceneParams.from_scene(sphere).medium.bounds_min,
              SceneParams.from_scene(sphere).medium.bounds_max)
    box = mi.load_dict(scene_dict(res=(32, 24), box={
        "type": "cube", **INTERIOR,
        "to_world": T().translate(((lo + hi) / 2).tolist()).scale(((hi - lo) / 2).tolist())}))
    integ = mi.load_dict({"type": "raymarch", "visibility": "exact"})
    a = np.array(integ.render_layers(sphere, spp=1)["scattering"])
    b = np.array(integ.render_layers(box, spp=1)["scattering"])
    assert abs(a.mean() / b.mean() - 1) > 0.05


@pytest.mark.parametrize("method", METHODS)
def test_camera_outside_a_sphere(method):
    d = scene_dict(res=(24, 18), box={"type": "sphere", **INTERIOR, "center": [0, 0, 0],
                                      "radius": 1.3})
    del d["sensor"]["medium"]
    scene = mi.load_dict(d)
    assert SceneParams.from_scene(scene).camera_outside
    assert_matches_the_exact_marcher(scene, method)


def test_a_sun_in_a_sphere_marches_minmax_and_says_so():
    with pytest.warns(UserWarning, match="sphere-bounded"):
        mi.load_dict({"type": "minmax_epipolar"}).render_layers(scene_with("sphere"), spp=1)


@pytest.mark.parametrize("method", METHODS)
def test_moving_the_boundary_compiles_nothing(method):
    """The boundary's frame and the medium's extent (margins scale with
    it) enter the kernels as opaque values."""
    from episcatter.kernels import kernel_log, literal_changes

    integ = mi.load_dict({"type": method})
    scene = scene_with("rotated box")
    with kernel_log() as first:
        integ.render_layers(scene, spp=1)
    params = mi.traverse(scene)
    key = "box.vertex_positions"
    v = dr.unravel(mi.Point3f, params[key])
    params[key] = dr.ravel(v + mi.Vector3f(0.02, -0.01, 0.03))
    params.update()
    with kernel_log() as log:
        integ.render_layers(scene, spp=1)
    assert log.compiled == 0, literal_changes(first, log)


# -- closed convex meshes -----------------------------------------------------------

def write_ply(path, vertices, faces) -> str:
    """An ASCII PLY file of a triangle mesh."""
    lines = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}",
             "property float x", "property float y", "property float z",
             f"element face {len(faces)}", "property list uchar int vertex_indices",
             "end_header"]
    lines += [" ".join(f"{x:.9g}" for x in v) for v in vertices]
    lines += ["3 " + " ".join(str(int(i)) for i in f) for f in faces]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def prism(sides: int, radius: float, y0: float, y1: float, centre=(0.0, 0.0)):
    """A closed prism with a regular ``sides``-gon as its base (outward winding)."""
    a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a)], 1)
    v = [[x, y0, z] for x, z in ring] + [[x, y1, z] for x, z in ring]
    f = []
    for i in range(sides):
        j = (i + 1) % sides
        f += [[i, sides + j, j], [i, sides + i, sides + j]]
    for i in range(1, sides - 1):
        f += [[0, i, i + 1], [sides, sides + i + 1, sides + i]]
    return np.array(v), np.array(f)


def mesh_scene(tmp_path, vertices, faces, light="directional", res=(32, 24)):
    ply = write_ply(tmp_path / "fog.ply", vertices, faces)
    return mi.load_dict(scene_dict(light=light, res=res,
                                   box={"type": "ply", "filename": ply, **INTERIOR}))


def test_a_convex_mesh_is_read_as_its_face_planes(tmp_path):
    params = SceneParams.from_scene(mesh_scene(tmp_path, *prism(6, 4.0, -2.0, 3.0)))
    assert params.medium.boundary == "convex" and len(params.medium.planes) == 8
    rng = np.random.default_rng(3)
    p, d = rng.uniform(-5, 5, (2000, 3)), rng.normal(size=(2000, 3))
    near, far = (np.array(x, np.float64) for x in medium_interval(
        params, mi.Point3f(*p.T.astype(np.float32)), mi.Vector3f(*d.T.astype(np.float32))))
    # the oracle: dense points along each line, inside where every n.x <= c
    t = np.linspace(-20, 20, 8001)
    x = p[:, None, :] + t[None, :, None] * d[:, None, :]
    P = params.medium.planes
    excess = np.max(x @ P[:, :3].T - P[:, 3], axis=2)      # > 0: outside some face
    inside = excess <= 1e-9
    hit = inside.any(1)
    first = t[np.argmax(inside, 1)]
    last = t[len(t) - 1 - np.argmax(inside[:, ::-1], 1)]
    step = (t[1] - t[0]) * 1.01
    seen = hit & (first > t[0]) & (last < t[-1])          # both ends inside the oracle's range
    assert seen.sum() > 300 and (~hit).sum() > 300
    np.testing.assert_allclose(near[seen], first[seen], atol=step)
    np.testing.assert_allclose(far[seen], last[seen], atol=step)
    wide = excess.min(1) > 0.5                              # misses by a margin
    assert wide.sum() > 300 and np.all(far[wide] < near[wide])


@pytest.mark.parametrize("light", ["directional", "point", "spot"])
@pytest.mark.parametrize("method", METHODS)
def test_every_integrator_in_a_convex_mesh(tmp_path, method, light):
    assert_matches_the_exact_marcher(
        mesh_scene(tmp_path, *prism(6, 3.0, -1.5, 2.5, centre=(0.0, 0.8)), light=light), method)


def test_exact_marcher_in_a_convex_mesh_agrees_with_volpath(tmp_path):
    assert_agrees_with_volpath(mesh_scene(tmp_path, *prism(6, 3.0, -1.5, 2.5, centre=(0.0, 0.8)),
                                          light="point", res=(24, 18)))


def test_non_convex_and_open_meshes_are_refused_with_the_reason(tmp_path):
    v, f = prism(6, 4.0, -2.0, 3.0)
    with pytest.raises(ValueError, match="not closed"):
        SceneParams.from_scene(mesh_scene(tmp_path, v, f[:-2]))
    mixed = f.copy()
    mixed[0] = mixed[0, ::-1]
    with pytest.raises(ValueError, match="not wound consistently"):
        SceneParams.from_scene(mesh_scene(tmp_path, v, mixed))
    with pytest.raises(ValueError, match="normals point inward"):
        SceneParams.from_scene(mesh_scene(tmp_path, v, f[:, ::-1]))
    # an L-shaped prism (outward winding): a dent
    v = np.array([[-3, -2, -3], [3, -2, -3], [3, -2, 0], [0, -2, 0], [0, -2, 3], [-3, -2, 3]],
                 float)
    v = np.concatenate([v, v + [0, 5, 0]])
    n = 6
    f = []
    for i in range(n):
        j = (i + 1) % n
        f += [[i, n + j, j], [i, n + i, n + j]]
    f += [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5]]
    f += [[n, n + 2, n + 1], [n, n + 3, n + 2], [n, n + 4, n + 3], [n, n + 5, n + 4]]
    with pytest.raises(ValueError, match="not convex"):
        SceneParams.from_scene(mesh_scene(tmp_path, v, np.array(f)))


@pytest.mark.parametrize("light", ["directional", "spot"])
@pytest.mark.parametrize("method", METHODS)
def test_the_axis_aligned_fast_path_agrees_with_the_general_one(monkeypatch, method, light):
    """An axis-aligned box clipped by the general affine-box test (its
    ``to_local``) renders as the closed-form slab path does, to float
    rounding: the fast path is the same boundary."""
    import dataclasses

    from integrators.template import base

    scene = mi.load_dict(scene_dict(light=light, res=(32, 24)))
    integ = mi.load_dict({"type": method})
    fast = np.array(integ.render_layers(scene, spp=1)["full"])
    read = SceneParams.from_scene

    def general(scene, sensor=None):
        params = read(scene, sensor)
        lo, hi = params.medium.bounds_min, params.medium.bounds_max
        A = np.diag(2.0 / (hi - lo))
        medium = dataclasses.replace(params.medium, to_local=np.concatenate(
            [A, (-A @ ((lo + hi) / 2))[:, None]], axis=1))
        assert not medium.axis_aligned
        return dataclasses.replace(params, medium=medium)
    monkeypatch.setattr(base.SceneParams, "from_scene", staticmethod(general))
    slow = np.array(integ.render_layers(scene, spp=1)["full"])
    np.testing.assert_allclose(slow, fast, rtol=2e-4, atol=1e-6 * fast.max())
