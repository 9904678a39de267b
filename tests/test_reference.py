"""Tests of episcatter.reference and the `reference` subcommand (tiny renders)."""

import argparse
import json
import os
import time

import numpy as np
import pytest

from episcatter import cmd_reference, reference
from episcatter.imageio import read_exr

SCENE = os.path.join(os.path.dirname(__file__), "data", "tiny_scene.xml")
TINY = {"res_x": 16, "res_y": 12}


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("EPISCATTER_CACHE", str(folder))
    return folder


def test_chunk_plan_gives_equal_halves():
    for spp, chunk in [(2, 1), (64, 16), (64, 64), (100, 16), (6, 4)]:
        sizes = reference.chunk_plan(spp, chunk)
        assert sum(sizes) == spp and len(sizes) % 2 == 0
        assert sum(sizes[0::2]) == sum(sizes[1::2]) == spp // 2
        assert max(sizes) <= chunk
    with pytest.raises(ValueError, match="even"):
        reference.chunk_plan(7, 2)


def test_cache_dir_follows_env(cache):
    assert reference.default_cache_dir() == str(cache)
    path = reference.reference_path(SCENE, TINY, 32)
    assert os.path.dirname(path) == str(cache)
    assert path.endswith("-spp32.exr") and "tiny_scene-volpath-" in path
    assert reference.reference_path(SCENE, {"res_x": 8}, 32) != path
    assert reference.reference_path(SCENE, TINY, 32, kind="exact") != path


def test_reference_is_cached_with_sidecar(cache):
    rgb, info = reference.render_reference(SCENE, TINY, spp=32, chunk=8, progress=False)
    assert rgb.shape == (12, 16, 3) and np.all(np.isfinite(rgb)) and rgb.mean() > 0
    assert not info["cached"]
    for key in ("spp", "chunk", "seeds", "wall_time_s", "resolution", "scene", "defines",
                "scene_key", "relmse_noise", "mitsuba", "drjit", "date", "integrator",
                "integrator_source"):
        assert key in info, key
    assert info["spp"] == 32 and info["chunk"] == 8 and info["seeds"] == [0, 1, 2, 3]
    assert info["resolution"] == [16, 12]
    assert info["integrator_source"] == "scene"  # tiny_scene uses volpath max_depth=2
    assert info["defines"] == {"res_x": "16", "res_y": "12"}

    path = reference.reference_path(SCENE, TINY, 32)
    assert info["path"] == path and os.path.isfile(reference.sidecar_path(path))
    layers = read_exr(path)
    assert set(layers) == {"full", "half_a", "half_b", "variance"}
    assert np.all(layers["variance"] >= 0)
    assert info["relmse_noise_chunks"]["block_1"] > 0
    np.testing.assert_allclose(layers["full"], 0.5 * (layers["half_a"] + layers["half_b"]),
                               rtol=1e-6, atol=1e-7)
    with open(reference.sidecar_path(path)) as f:
        assert json.load(f)["scene_key"] == info["scene_key"]

    t0 = time.perf_counter()
    rgb2, info2 = reference.render_reference(SCENE, TINY, spp=32, chunk=8, progress=False)
    assert time.perf_counter() - t0 < 0.5
    assert info2["cached"] and np.array_equal(rgb, rgb2)
    assert reference.find_cached_reference(SCENE, TINY) == path
    assert reference.find_cached_reference(SCENE, {"res_x": 8}) is None


def test_noise_estimate_positive_and_shrinks(cache):
    _, low = reference.render_reference(SCENE, TINY, spp=16, chunk=4, progress=False)
    _, high = reference.render_reference(SCENE, TINY, spp=256, chunk=64, progress=False)
    n_low, n_high = low["relmse_noise"], high["relmse_noise"]
    assert n_low["eps"] == pytest.approx(0.01)
    for k in ("block_1", "block_4", "block_8"):
        assert n_low[k] > 0 and n_high[k] > 0
    for k in ("block_1", "block_4"):  # block 8 leaves 2 blocks: too few to compare
        assert n_high[k] < 0.5 * n_low[k]  # ~1/16 expected for 16x the samples
    assert n_low["block_4"] < n_low["block_1"]


def test_force_rerenders(cache):
    _, a = reference.render_reference(SCENE, TINY, spp=4, chunk=2, progress=False)
    _, b = reference.render_reference(SCENE, TINY, spp=4, chunk=2, progress=False, force=True)
    assert not b["cached"] and b["date"] >= a["date"]


def test_fresh_volpath_when_scene_integrator_differs(cache, tmp_path):
    text = open(SCENE).read().replace('<integer name="max_depth" value="2"/>',
                                      '<integer name="max_depth" value="5"/>')
    scene = tmp_path / "deep.xml"
    scene.write_text(text)
    _, info = reference.render_reference(str(scene), TINY, spp=2, chunk=1, progress=False)
    assert info["integrator_source"] == "fresh"
    assert "max_depth=2" in info["integrator"]


def test_exact_reference_is_deterministic_at_pixel_centres(cache):
    # chunk=1: one unjittered sample per pixel per chunk, so both halves agree.
    rgb, info = reference.render_reference(SCENE, TINY, spp=2, chunk=1, kind="exact",
                                           steps=32, progress=False)
    assert info["kind"] == "exact" and info["settings"]["steps"] == 32
    assert info["relmse_noise"]["block_1"] == 0.0
    assert rgb.shape == (12, 16, 3) and rgb.mean() > 0


def test_pixel_centre_reference_renders_its_image_once(cache):
    # Bug (issue 10): the 1-spp exact reference rendered the same image twice,
    # once per half.  It is deterministic, so one chunk is rendered and shared;
    # a direct render at another seed gives the same bits.
    rgb, info = reference.render_reference(SCENE, TINY, spp=2, chunk=1, kind="exact",
                                           steps=32, progress=False)
    assert info["chunks_rendered"] == 1
    assert info["chunks"][1]["run"].startswith("copy of seed 0")
    scene = reference.load_scene(SCENE, TINY)
    integ, _, _ = reference.reference_integrator(scene, "exact", 32)
    other = reference.render_rgb(scene, integ, spp=1, seed=1)
    assert np.array_equal(other.astype(np.float32), rgb)


def test_unwrap_render_error():
    inner = ValueError("unsupported camera")
    try:
        try:
            raise inner
        except ValueError as e:
            raise RuntimeError("custom op failed") from e
    except RuntimeError as outer:
        assert reference.unwrap_render_error(outer) is inner
    plain = RuntimeError("other")
    assert reference.unwrap_render_error(plain) is plain


def test_cli_writes_exr_json_png(cache, tmp_path, capsys):
    parser = argparse.ArgumentParser()
    cmd_reference.add_arguments(parser)
    out = tmp_path / "out" / "ref.exr"
    args = parser.parse_args([SCENE, "--spp", "8", "--chunk", "4", "-D", "res_x=16",
                              "-D", "res_y=12", "-o", str(out), "--no-progress"])
    assert cmd_reference.run(args) == 0
    for suffix in (".exr", ".json", ".png"):
        assert os.path.isfile(str(out.with_suffix(suffix)))
    text = capsys.readouterr().out
    assert str(out) in text and "relMSE noise" in text and "rendered" in text
    assert cmd_reference.run(args) == 0
    assert "from the cache" in capsys.readouterr().out


# --------------------------------------------------------------------------
# The cache key covers every file the scene loads (issue 10, defect 2)
# --------------------------------------------------------------------------

QUAD_OBJ = "v -1 0.5 -1\nv 1 0.5 -1\nv 1 0.5 1\nv -1 0.5 1\nf 1 2 3\nf 1 3 4\n"


def _scene_with_mesh(folder, mesh_text=QUAD_OBJ):
    """tiny_scene plus an .obj blocker named through a <default> and $mesh,
    and its sphere moved to an included XML file in a subfolder."""
    text = open(SCENE).read()
    start = text.index('    <shape type="sphere">')
    end = text.index("</shape>", start) + len("</shape>")
    sphere = text[start:end]
    (folder / "parts").mkdir(exist_ok=True)
    (folder / "parts" / "sphere.xml").write_text(
        f'<scene version="3.0.0">\n{sphere}\n</scene>\n')
    (folder / "meshes").mkdir(exist_ok=True)
    (folder / "meshes" / "blocker.obj").write_text(mesh_text)
    text = text[:start] + (
        '    <default name="mesh" value="blocker"/>\n'
        '    <include filename="parts/sphere.xml"/>\n'
        '    <shape type="obj">\n'
        '        <string name="filename" value="meshes/$mesh.obj"/>\n'
        '        <transform name="to_world"><translate value="0, 3, 0"/></transform>\n'
        '    </shape>') + text[end:]
    path = folder / "mesh_scene.xml"
    path.write_text(text)
    return str(path)


def test_scene_files_walks_defaults_includes_and_paths(tmp_path):
    from episcatter.scene_files import scene_files

    scene = _scene_with_mesh(tmp_path)
    files = scene_files(scene, TINY)
    assert [(f.role, f.name) for f in files] == [("include", "parts/sphere.xml"),
                                                 ("filename", "meshes/blocker.obj")]
    assert files[1].path == str(tmp_path / "meshes" / "blocker.obj")
    # a -D define wins over the <default>; the longest $name is substituted first
    (tmp_path / "meshes" / "blocker_x.obj").write_text(QUAD_OBJ)
    other = scene_files(scene, {"mesh": "blocker_x", "me": "nope"})
    assert other[1].path == str(tmp_path / "meshes" / "blocker_x.obj")
    # <path> folders are searched for plugin files, and a spectrum file counts
    (tmp_path / "assets").mkdir()
    (tmp_path / "assets" / "glass.spd").write_text("400 1\n700 1\n")
    (tmp_path / "scene2.xml").write_text(
        '<scene version="3.0.0"><path value="assets"/>'
        '<bsdf type="diffuse"><spectrum name="reflectance" filename="glass.spd"/></bsdf>'
        '</scene>')
    files = scene_files(tmp_path / "scene2.xml")
    assert [(f.role, f.path) for f in files] == [("spectrum", str(tmp_path / "assets" / "glass.spd"))]


def test_include_cycle_is_a_clear_error(tmp_path):
    from episcatter.scene_files import scene_files

    (tmp_path / "a.xml").write_text('<scene version="3.0.0"><include filename="a.xml"/></scene>')
    with pytest.raises(ValueError, match="include"):
        scene_files(tmp_path / "a.xml")


def test_editing_a_loaded_mesh_misses_the_cache(cache, tmp_path):
    scene = _scene_with_mesh(tmp_path)
    _, first = reference.render_reference(scene, TINY, spp=2, chunk=1, progress=False)
    assert not first["cached"]
    # same bytes written again: a hit
    (tmp_path / "meshes" / "blocker.obj").write_text(QUAD_OBJ)
    _, again = reference.render_reference(scene, TINY, spp=2, chunk=1, progress=False)
    assert again["cached"] and again["path"] == first["path"]
    # the blocker moved up: the key changes, the reference is rendered anew
    (tmp_path / "meshes" / "blocker.obj").write_text(QUAD_OBJ.replace("0.5", "0.7"))
    _, edited = reference.render_reference(scene, TINY, spp=2, chunk=1, progress=False)
    assert not edited["cached"] and edited["path"] != first["path"]
    assert reference.find_cached_reference(scene, TINY) == edited["path"]
    # the included XML counts too
    inc = tmp_path / "parts" / "sphere.xml"
    inc.write_text(inc.read_text().replace('radius" value="1"', 'radius" value="0.9"'))
    assert reference.reference_key(scene, TINY) != edited["scene_key"]


def test_scene_without_files_keeps_its_key():
    # the shipped references of file-free scenes keep their names
    import scenes
    assert reference.reference_key(scenes.path("beam"), {"res_x": 48, "res_y": 36}) == \
        "dd03c18e6c6b3ce3"


# --------------------------------------------------------------------------
# Chunks are stored as they finish; an interrupted reference resumes (issue 17)
# --------------------------------------------------------------------------

class Interrupt(KeyboardInterrupt):
    """Raised by an on_chunk hook to stop a render as Ctrl-C would."""


def stop_after(n):
    def hook(done, total):
        if done >= n:
            raise Interrupt(f"{done} of {total}")
    return hook


def test_interrupted_reference_resumes_with_the_missing_chunks(cache):
    args = dict(spp=16, chunk=2, progress=False)      # 8 chunks
    with pytest.raises(Interrupt):
        reference.render_reference(SCENE, TINY, on_chunk=stop_after(3), **args)
    path = reference.reference_path(SCENE, TINY, 16)
    assert not os.path.exists(path)
    store = reference.ChunkStore(reference.chunk_folder(path))
    assert len(store.stored(list(enumerate(reference.chunk_plan(16, 2))))) == 3

    rgb, info = reference.render_reference(SCENE, TINY, **args)
    assert (info["chunks_rendered"], info["chunks_resumed"]) == (5, 3)
    assert [c["run"] for c in info["chunks"]].count("earlier") == 3
    assert [c["seed"] for c in info["chunks"]] == info["seeds"] == list(range(8))
    assert not os.path.exists(reference.chunk_folder(path))     # removed once merged

    fresh, again = reference.render_reference(SCENE, TINY, force=True, **args)
    assert again["chunks_rendered"] == 8
    assert np.array_equal(rgb, fresh)


def test_merge_is_in_chunk_order():
    rng = np.random.default_rng(1)
    images = [rng.random((3, 4, 3), dtype=np.float32) for _ in range(6)]
    sizes = [3, 3, 2, 2, 2, 2]
    a, b, var = reference.merge_chunks(images, sizes)
    np.testing.assert_allclose(a, sum(i * n for i, n in zip(images[0::2], sizes[0::2])) / 7, rtol=1e-6)
    np.testing.assert_allclose(b, sum(i * n for i, n in zip(images[1::2], sizes[1::2])) / 7, rtol=1e-6)
    assert var.shape == a.shape and np.all(var >= 0)


def test_a_process_seeing_other_files_refuses_to_render(tmp_path):
    scene = _scene_with_mesh(tmp_path)
    key = reference.reference_key(scene, TINY)
    job = reference.ChunkJob(scene, tuple(sorted((k, str(v)) for k, v in TINY.items())),
                             "volpath", None, key)
    assert reference.render_chunk(job, (0, 1))["image"].shape == (12, 16, 3)
    (tmp_path / "meshes" / "blocker.obj").write_text(QUAD_OBJ.replace("0.5", "0.6"))
    stale = reference.ChunkJob(job.scene_path, job.defines, "volpath", None, key + "x")
    with pytest.raises(ValueError, match="files differ"):
        reference.render_chunk(stale, (0, 1))


def test_cli_ctrl_c_says_how_to_resume(monkeypatch, capsys):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cmd_reference, "render_reference", interrupted)
    from episcatter import cli
    assert cli.main(["reference", SCENE, "--no-progress"]) == 130
    assert "run the same command again" in capsys.readouterr().err
