"""The scene suite: conventions, geometry sanity, asset sizes, determinism."""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

if mi.variant() is None:
    mi.set_variant("llvm_ad_rgb")

import scenes  # noqa: E402
from scenes import assets, generate, meshes, textures  # noqa: E402

EMITTER_CLASS = {"directional": "DirectionalEmitter", "point": "PointLight",
                 "spot": "SpotLight"}


# -- helpers -------------------------------------------------------------------
def _mat(transform) -> np.ndarray:
    return np.array(transform.matrix, dtype=np.float64).reshape(4, 4)


def _load(name: str, **params):
    return mi.load_file(scenes.path(name), res_x=16, res_y=12, spp=4, **params)


def _stem(name: str) -> str:
    return name.removesuffix(generate.LIT_SUFFIX)


def _box(scene):
    return next(s for s in scene.shapes() if s.id() == "medium_box")


def _bbox(shape) -> tuple[np.ndarray, np.ndarray]:
    b = shape.bbox()
    return np.array(b.min, dtype=float).ravel(), np.array(b.max, dtype=float).ravel()


def _camera_origin(scene) -> np.ndarray:
    return (_mat(scene.sensors()[0].world_transform()) @ [0, 0, 0, 1])[:3]


def _light_homogeneous(emitter) -> np.ndarray:
    """Position (w = 1) of a point/spot light, or the direction toward a
    directional light (w = 0)."""
    params = mi.traverse(emitter)
    if "position" in params:
        return np.append(np.array(params["position"], dtype=float).ravel(), 1.0)
    to_world = _mat(params["to_world"])
    if emitter.class_name() == "SpotLight":
        return to_world @ [0, 0, 0, 1]
    return -(to_world @ [0, 0, 1, 0])


def _epipole_ndc(scene) -> np.ndarray:
    """The light's projection in units of the half film width/height
    (on screen iff both |coordinates| < 1 and it lies in front)."""
    sensor = scene.sensors()[0]
    p = np.linalg.inv(_mat(sensor.world_transform())) @ _light_homogeneous(scene.emitters()[0])
    tan_x = np.tan(np.radians(float(np.array(mi.traverse(sensor)["x_fov"]).ravel()[0])) / 2)
    w, h = sensor.film().size()
    return np.array([p[0] / p[2] / tan_x, p[1] / p[2] / (tan_x * h / w), p[2]])


def _exit_distance(lo, hi, origin, direction) -> float:
    with np.errstate(divide="ignore"):
        t1, t2 = (lo - origin) / direction, (hi - origin) / direction
    return float(np.min(np.maximum(t1, t2)))


def _ray(origins, direction, maxt) -> mi.Ray3f:
    """Rays from ``origins`` ((3,) or (n, 3)) along ``direction`` up to ``maxt``."""
    o = np.atleast_2d(np.asarray(origins, dtype=np.float32))
    d = np.asarray(direction, dtype=np.float32)
    ray = mi.Ray3f(mi.Point3f(*(mi.Float(c) for c in o.T)),
                   mi.Vector3f(*(float(c) for c in d)))
    ray.maxt = mi.Float(np.broadcast_to(np.asarray(maxt, dtype=np.float32), len(o)).copy())
    return ray


def _xml(name: str) -> ET.Element:
    return ET.parse(Path(scenes.path(name))).getroot()


# -- suite listing ---------------------------------------------------------------
def test_suite_names_and_files():
    assert scenes.SUITE == ["nave_offscreen", "nave_onscreen", "grove", "terrain",
                            "spot_room", "point_fog", "beam"]
    assert scenes.LIT_SUITE == [n + "_lit" for n in scenes.SUITE]
    for name in scenes.ALL_SCENES:
        assert Path(scenes.path(name)).is_file()
    with pytest.raises(ValueError, match="unknown scene"):
        scenes.path("no_such_scene")


# -- XML conventions ---------------------------------------------------------------
@pytest.mark.parametrize("name", scenes.ALL_SCENES)
def test_xml_conventions(name):
    root = _xml(name)
    assert root.get("version") == "3.0.0"
    defaults = {d.get("name"): d.get("value") for d in root.findall("default")}
    assert defaults["res_x"] == "320" and defaults["res_y"] == "240"
    assert defaults["spp"] == "64"
    assert 0 < float(defaults["sigma_t"]) and 0 < float(defaults["albedo"]) <= 1
    integ = root.find("integrator")
    assert integ.get("type") == "volpath"
    assert integ.find("integer[@name='max_depth']").get("value") == "2"
    medium = root.find("medium")
    assert medium.get("type") == "homogeneous" and medium.get("id") == "medium"
    assert medium.find("*[@name='sigma_t']").get("value") == "$sigma_t"
    assert medium.find("*[@name='albedo']").get("value") == "$albedo"
    phase = medium.find("phase")
    assert phase.get("type") in ("hg", "isotropic", "rayleigh")
    if phase.get("type") == "hg":
        assert phase.find("float[@name='g']").get("value") == "$g"
        assert -1 < float(defaults["g"]) < 1
    else:
        assert "g" not in defaults
    sensors = root.findall("sensor")
    assert len(sensors) == 1 and sensors[0].get("type") == "perspective"
    sensor = sensors[0]
    assert sensor.find("transform/lookat") is not None
    assert sensor.find("ref").get("id") == "medium"
    assert sensor.find("sampler").get("type") == "independent"
    assert sensor.find("sampler/integer[@name='sample_count']").get("value") == "$spp"
    film = sensor.find("film")
    assert film.get("type") == "hdrfilm"
    assert film.find("integer[@name='width']").get("value") == "$res_x"
    assert film.find("integer[@name='height']").get("value") == "$res_y"
    assert film.find("rfilter").get("type") == "box"
    assert film.find("string[@name='pixel_format']").get("value") == "rgb"
    emitters = root.findall("emitter")
    assert tuple(e.get("type") for e in emitters) == scenes.EMITTER_TYPES[_stem(name)]
    assert [e.get("id") for e in emitters] == ["light"] + [f"light_{k}" for k in
                                                           range(2, len(emitters) + 1)]
    boundary = [s for s in root.findall("shape") if s.find("ref[@name='interior']") is not None]
    assert [s.get("id") for s in boundary] == ["medium_box"]
    box = boundary[0]
    assert box.get("type") == "cube" and box.find("bsdf").get("type") == "null"
    assert [op.tag for op in box.find("transform")] == ["scale", "translate"]


def test_defaults_override():
    scene = _load("grove", sigma_t=0.5, albedo="0.5, 0.6, 0.7", g=-0.2)
    medium = scene.sensors()[0].get_medium()
    params = mi.traverse(medium)
    assert np.allclose(np.array(params["sigma_t.value.value"]).ravel(), 0.5)
    assert np.allclose(np.array(params["albedo.value.value"]).ravel(), [0.5, 0.6, 0.7])
    g = mi.traverse(medium.phase_function())["g"]
    assert np.allclose(np.array(g).ravel(), -0.2)
    film = scene.sensors()[0].film()
    assert tuple(film.size()) == (16, 12)


# -- loaded scene structure -----------------------------------------------------------
@pytest.mark.parametrize("name", scenes.ALL_SCENES)
def test_loaded_scene_structure(name):
    scene = _load(name)
    assert [e.class_name() for e in scene.emitters()] == [
        EMITTER_CLASS[kind] for kind in scenes.EMITTER_TYPES[_stem(name)]]
    medium = scene.sensors()[0].get_medium()
    assert medium is not None and medium.class_name() == "HomogeneousMedium"
    boundary = [s for s in scene.shapes() if s.interior_medium() is not None]
    assert len(boundary) == 1 and boundary[0].id() == "medium_box"
    box = boundary[0]
    assert mi.has_flag(box.bsdf().flags(), mi.BSDFFlags.Null)
    assert box.bsdf().class_name() in ("Null", "NullBSDF")
    assert box.interior_medium().ptr == medium.ptr
    lo, hi = _bbox(box)
    verts = np.array(mi.traverse(box)["vertex_positions"], dtype=float).reshape(-1, 3)
    assert np.all(np.isclose(verts, lo) | np.isclose(verts, hi)), "box not axis-aligned"
    assert np.all(lo < _camera_origin(scene)) and np.all(_camera_origin(scene) < hi)
    for emitter in scene.emitters():
        light = _light_homogeneous(emitter)
        if light[3] == 1:
            assert np.all(lo < light[:3]) and np.all(light[:3] < hi)
    lit = name.endswith(generate.LIT_SUFFIX)
    any_colour = False
    for shape in scene.shapes():
        if shape is box or shape.ptr == box.ptr:
            continue
        s_lo, s_hi = _bbox(shape)
        assert np.all(lo <= s_lo) and np.all(s_hi <= hi), f"{shape.id()} leaves the box"
        assert shape.bsdf().class_name() == "SmoothDiffuse"
        refl = np.array(mi.traverse(shape.bsdf())["reflectance.value"]).ravel()
        any_colour |= bool(np.any(refl > 0))
        if not lit:
            assert np.all(refl == 0), f"{shape.id()} is not black"
    assert any_colour == lit


# -- big meshes -----------------------------------------------------------------------
def _triangles(scene) -> int:
    return sum(s.face_count() for s in scene.shapes() if s.is_mesh() and s.id() != "medium_box")


def test_grove_has_many_leaves():
    scene = _load("grove")
    leaves = next(s for s in scene.shapes() if s.id() == "leaves")
    assert leaves.face_count() >= 100_000
    assert _triangles(scene) >= 100_000


def test_terrain_has_a_million_triangles():
    scene = _load("terrain")
    assert _triangles(scene) >= 1_000_000


# -- light geometry -----------------------------------------------------------------------
def test_nave_epipoles():
    off = _epipole_ndc(_load("nave_offscreen"))
    assert max(abs(off[0]), abs(off[1])) > 1.5, "epipole should be far off-screen"
    on = _epipole_ndc(_load("nave_onscreen"))
    assert on[2] > 0 and abs(on[0]) < 0.8 and abs(on[1]) < 0.8, "epipole should be on-screen"


def test_nave_onscreen_sun_visible_through_window():
    scene = _load("nave_onscreen")
    origin = _camera_origin(scene)
    toward_sun = _light_homogeneous(scene.emitters()[0])[:3]
    lo, hi = _bbox(_box(scene))
    ray = _ray(origin, toward_sun, _exit_distance(lo, hi, origin, toward_sun) * (1 - 1e-4))
    assert not bool(np.array(scene.ray_test(ray)).ravel()[0])


def test_beam_passes_through_the_hole():
    """Some light reaches the floor through the ceiling hole, most does not."""
    scene = _load("beam")
    toward_sun = _light_homogeneous(scene.emitters()[0])[:3]
    lo, hi = _bbox(_box(scene))
    xs, zs = np.meshgrid(np.linspace(-4.9, 4.9, 99), np.linspace(-4.9, 4.9, 99))
    pts = np.stack([xs.ravel(), np.full(xs.size, 0.01), zs.ravel()], 1)
    ray = _ray(pts, toward_sun, [_exit_distance(lo, hi, p, toward_sun) * (1 - 1e-4)
                                 for p in pts])
    lit = ~np.array(scene.ray_test(ray), dtype=bool).ravel()
    assert 0 < lit.mean() < 0.01


@pytest.mark.parametrize("name", scenes.SUITE)
def test_volpath_renders_something(name):
    scene = mi.load_file(scenes.path(name), res_x=64, res_y=48, spp=16)
    img = np.array(mi.render(scene, seed=3))
    assert np.all(np.isfinite(img))
    assert img.max() > 0


# -- determinism and assets ---------------------------------------------------------------
def test_generation_is_deterministic_and_committed_xml_is_current():
    first, second = generate.scene_texts(), generate.scene_texts()
    assert first == second
    assert sorted(first) == sorted(scenes.ALL_SCENES)
    for stem, text in first.items():
        on_disk = (assets.SCENE_DIR / f"{stem}.xml").read_text(encoding="utf-8")
        assert on_disk == text, f"{stem}.xml is stale: run python -m scenes.generate"


def test_write_scenes(tmp_path):
    paths = generate.write_scenes(tmp_path)
    assert len(paths) == len(scenes.ALL_SCENES)
    assert paths[0].read_bytes() == (assets.SCENE_DIR / paths[0].name).read_bytes()


def test_asset_builders_are_deterministic():
    trees = meshes.place_trees(3, (0.0, 0.0), 5.0, 2.0, seed=1)
    a = meshes.ply_bytes(*meshes.grove_leaves(trees, 200, seed=2))
    b = meshes.ply_bytes(*meshes.grove_leaves(trees, 200, seed=2))
    assert a == b
    h = meshes.terrain_heights(33, 100.0, seed=5, relief=10.0)
    assert np.array_equal(h, meshes.terrain_heights(33, 100.0, seed=5, relief=10.0))
    glass = textures.stained_glass(32, panes=6, seed=1)
    assert textures.png_bytes(glass) == textures.png_bytes(textures.stained_glass(32, 6, 1))


def test_ply_round_trip(tmp_path):
    v, f, n = meshes.grid_mesh(np.zeros((4, 4)), 3.0)
    path = tmp_path / "grid.ply"
    meshes.write_atomic(path, meshes.ply_bytes(v, f, n))
    mesh = mi.load_dict({"type": "ply", "filename": str(path)})
    assert mesh.face_count() == 18 and mesh.vertex_count() == 16
    normals = np.array(mi.traverse(mesh)["vertex_normals"]).reshape(-1, 3)
    assert np.allclose(normals, [0, 1, 0])
    # counter-clockwise seen from +y: geometric normals point up
    params = mi.traverse(mesh)
    pos = np.array(params["vertex_positions"]).reshape(-1, 3)
    tri = pos[np.array(params["faces"]).reshape(-1, 3)]
    geo_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(geo_n[:, 1] > 0) and np.allclose(geo_n[:, [0, 2]], 0)


def test_ensure_assets_is_idempotent():
    scenes.ensure_assets()
    assert scenes.ensure_assets() == []
    for asset in assets.ASSETS:
        assert asset.is_current()
