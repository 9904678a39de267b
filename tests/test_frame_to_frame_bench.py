"""The fly-through benchmark (``experiments.frame_to_frame``,
``episcatter.flythrough``, ``episcatter bench --frames``) on a tiny image:
columns and kernel counts only, no timing assertions."""
from __future__ import annotations

import csv

import mitsuba as mi
import pytest

from episcatter import flythrough
from tests.conftest import scene_dict

import integrators  # noqa: F401  (variant, plugins)


def test_frame_schedule():
    assert [flythrough.frame_change(k) for k in range(7)] == [
        "first", "camera", "camera", "light", "medium", "all", "camera"]


@pytest.mark.parametrize("light", ["directional", "point", "spot", "spot_textured"])
def test_animated_keys_and_changes(light):
    scene = mi.load_dict(scene_dict(light=light, res=(8, 6)))
    params = mi.traverse(scene)
    keys = flythrough.animated_keys(scene, params)
    assert keys.camera in params.keys() and keys.light in params.keys()
    assert keys.light_kind == ("position" if light == "point" else "to_world")
    assert keys.sigma_t is not None
    before = {k: str(params[k]) for k in (keys.camera, keys.light, keys.sigma_t)}
    import random
    moved = flythrough.apply_change(params, keys, "all", flythrough.Motion(seed=1),
                                    random.Random(1))
    params.update()
    assert set(moved) >= {"camera_dx", "sigma_factor"}
    for k, v in before.items():
        assert str(params[k]) != v, k


def test_fly_through_rows():
    scene = mi.load_dict(scene_dict(light="point", res=(12, 9)))
    rows = flythrough.fly_through(scene, mi.load_dict({"type": "raymarch"}), frames=3,
                                  warm_repeats=1, motion=flythrough.Motion(seed=3))
    assert [r["frame"] for r in rows] == [0, 1, 2]
    for r in rows:
        assert set(flythrough.FRAME_COLUMNS) <= set(r)
        assert 0 <= r["compiled"] <= r["launched"]
        assert r["from_disk"] + r["compiled"] <= r["launched"]
        assert r["wall_s"] > 0 and r["warm_s"] > 0
    s = flythrough.summarize_frames(rows)
    assert s["new_frames"] == 2 and s["compiled_max"] <= s["launched_max"]
    assert "| frame | change |" in flythrough.format_frames(rows, "t")


def test_experiment_outputs(tmp_path):
    from experiments import frame_to_frame

    out = tmp_path / "f2f"
    pairs = frame_to_frame.main(["--in-process", "--size", "24x18", "--frames", "3",
                                 "--warm-repeats", "1", "--methods", "raymarch",
                                 "--scenes", "point_fog", "--out", str(out), "--no-progress"])
    assert len(pairs) == 1 and not pairs[0].get("error"), pairs
    with open(out / "frames.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3
    for col in ("scene", "method", "width", "height", "frame", "change", "wall_s", "warm_s",
                "ratio", "compile_s", "compile_share", "launched", "compiled", "from_disk"):
        assert col in rows[0], col
    for r in rows:
        assert r["scene"] == "point_fog" and r["method"] == "raymarch"
        assert (r["width"], r["height"]) == ("24", "18")
        assert 0 <= int(r["compiled"]) <= int(r["launched"])
    table = (out / "table.md").read_text()
    for head in ("first render s", "new frame mean s", "new frame max s", "warm s",
                 "max ratio", "max compile share", "launched / frame",
                 "compiled / new frame (max)"):
        assert head in table, head
    assert "| point_fog | raymarch |" in table
    assert (out / "environment.json").exists() and (out / "pairs.csv").exists()


def test_plain_spot_scene():
    from experiments import frame_to_frame

    scene = frame_to_frame.load_scene("spot_room_plain", 8, 6)
    params = mi.traverse(scene)
    assert not any(k.endswith(".texture.data") for k in params.keys())   # no bitmap
    assert flythrough.animated_keys(scene, params).light_kind == "to_world"


def test_bench_frames_cli(tmp_path, capsys):
    from episcatter.cli import main
    from experiments.common import scene_file

    rc = main(["bench", scene_file("point_fog"), "-i", "raymarch", "-D", "res_x=16",
               "-D", "res_y=12", "--frames", "2", "--warm-repeats", "1",
               "--out", str(tmp_path)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "| frame | change | wall s | warm s |" in text
    with open(tmp_path / "frames.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["change"] for r in rows] == ["first", "camera"]
    assert all(int(r["compiled"]) <= int(r["launched"]) for r in rows)
