"""episcatter animate (CLI) and the animated-scene generators."""
import csv

import numpy as np

from episcatter.cli import main
from scenes.temporal import TABLE1_MOTION, blob_mesh, nave_swing, write_table1


def test_blob_mesh_is_closed_with_the_asked_triangle_count():
    for n in (2000, 50_000):
        v, f = blob_mesh(n)
        assert abs(len(f) - n) < 0.02 * n
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        assert np.all(counts == 2)   # every edge shared by two triangles: closed


def test_animate_writes_frames_csv_and_gif(tmp_path, capsys):
    xml = write_table1(tmp_path, triangles=(2000,))[0]
    out = tmp_path / "anim"
    rc = main(["animate", str(xml), "-i", "raymarch", "-p", "steps=16", "-p", "march=hybrid",
               "-D", "res_x=24", "-D", "res_y=24", "--frames", "3", "--move", TABLE1_MOTION,
               "-o", str(out)])
    assert rc == 0
    for k in range(3):
        assert (out / f"frame_{k:04d}.exr").exists() and (out / f"frame_{k:04d}.png").exists()
    assert (out / "animation.gif").stat().st_size > 0
    rows = list(csv.DictReader(open(out / "frames.csv")))
    assert [r["frame"] for r in rows] == ["0", "1", "2"]
    assert rows[0]["recomputed_fraction"] == "1.0" and float(rows[1]["recomputed_fraction"]) < 1
    assert "stage_mask_s" in rows[0] and "stage_scattering_s" in rows[0]
    assert "fps" in capsys.readouterr().out


def test_animate_reuses_slices_of_epipolar_tree(tmp_path):
    xml = write_table1(tmp_path, triangles=(2000,))[0]
    out = tmp_path / "tree"
    assert main(["animate", str(xml), "-i", "epipolar_tree", "-D", "res_x=32", "-D", "res_y=32",
                 "--frames", "2", "--move", TABLE1_MOTION, "-o", str(out)]) == 0
    rows = list(csv.DictReader(open(out / "frames.csv")))
    assert float(rows[1]["recomputed_fraction"]) < 1 and rows[1]["whole_frame"] == ""
    assert "stage_widen_s" in rows[1] and "stage_scattering.sweep_s" in rows[1]


def test_animate_names_a_missing_move(tmp_path, capsys):
    xml = write_table1(tmp_path, triangles=(2000,))[0]
    assert main(["animate", str(xml), "--frames", "2", "-o", str(tmp_path / "a")]) == 2
    assert "--move" in capsys.readouterr().err


def test_nave_swing_has_the_swinger():
    assert 'id="swinger"' in nave_swing().to_string()
