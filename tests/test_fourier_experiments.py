"""The fourier_* experiments: their --quick runs write complete outputs, and
the small helpers they are built from do what they say."""
import json
import math

import numpy as np
import pytest

from experiments import (fourier_scene_independence, fourier_speedup, fourier_table2,
                         fourier_weights, projective_angles)
from tests.conftest import read_csv


def read_json(path):
    with open(path) as f:
        return json.load(f)


def check_outputs(out, names):
    """Every named file exists, is small, and the JSON holds the settings
    and the environment (versions, threads, load)."""
    for name in names:
        path = out / name
        assert path.is_file(), name
        assert 0 < path.stat().st_size < 500_000, name
        if name.endswith(".json"):
            doc = read_json(path)
            assert doc["settings"]["quick"] is True
            assert {"mitsuba", "drjit", "drjit_threads", "load_average"} <= set(doc["environment"])


# --------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------

def test_memory_is_rows_texels_coefficients_float32():
    assert fourier_table2.memory_mb(1024, 1024, 32) == 128.0      # paper: 32 MB at 8 bits
    assert fourier_table2.memory_mb(0, 1024, 32) == 0.0


def test_paper_time_excludes_the_shadow_map_build():
    stages = {"scattering": 1.0, "blockers": 0.25, "svd": 0.5}
    assert fourier_table2.paper_time(stages) == 0.75
    assert fourier_speedup.paper_seconds("fourier_filter", stages) == 0.75
    assert fourier_speedup.paper_seconds("raymarch", {"scattering": 1.0, "shadowmap": 0.9}) \
        == pytest.approx(0.1)
    assert fourier_table2.dominant_stage(stages) == "svd"


def test_table2_grid_is_the_papers():
    s = fourier_table2.settings_for(quick=False)
    runs = fourier_table2.runs_of(s)
    assert len(runs) == 10 + 3                       # Table 2 rows + regions 2..4
    assert runs["4096x1024 M32"] == {"light_rays": 4096, "slices": 1024, "coefficients": 32}
    assert runs["1024x1024 M32 R3"]["regions"] == 3
    assert (s["width"], s["height"]) == (1920, 1080)


def test_recording_filter_logs_its_maps_without_patching(make_scene):
    """The probe overrides the ``rectified_map`` stage (no module global is
    replaced) and renders the same image as ``fourier_filter``."""
    from integrators.fourier import rectified_map as ff
    import mitsuba as mi

    original = ff.rectified_shadow_map
    log = []
    scene = make_scene(res=(16, 12))
    probe = fourier_table2.recording_filter({"light_rays": 40}, log)
    img = np.array(mi.render(scene, integrator=probe))
    assert ff.rectified_shadow_map is original
    assert log and log[-1]["texels"] == 40 and 0 <= log[-1]["filtered_rows"] <= log[-1]["rows"]
    plain = np.array(mi.render(scene, integrator=mi.load_dict({"type": "fourier_filter",
                                                                "light_rays": 40})))
    assert np.array_equal(img, plain)


def test_normalised_relmse_is_scale_free():
    rng = np.random.default_rng(1)
    ref = rng.random((8, 8, 3)) + 0.5
    img = ref * 1.1
    assert fourier_weights.normalised_relmse(img * 1e-3, ref * 1e-3) == \
        pytest.approx(fourier_weights.normalised_relmse(img, ref), rel=1e-9)
    assert fourier_weights.normalised_relmse(ref, ref) == 0.0


def test_scene_independence_ratios():
    rows = [{"scene": s, "setting": "fixed", "status": "ok", "scattering_s": t, "paper_s": t,
             "time_s": t, **{f"{st}_ms": 1.0 for st in fourier_table2.STAGES}, "ring_ms": t / 2}
            for s, t in (("a", 1.0), ("b", 1.2), ("c", 1.5))]
    rows.append({"scene": "p", "setting": "fixed", "status": "not supported yet: point"})
    by = {r["quantity"]: r for r in fourier_scene_independence.ratios(rows)}
    assert by["scattering"]["ratio"] == pytest.approx(1.5)
    assert by["scattering"]["max_scene"] == "c" and by["scattering"]["min_scene"] == "a"
    assert by["scattering"]["meets_target"] is False
    assert by["svd"]["ratio"] == 1.0 and by["svd"]["meets_target"] is None
    assert "ring" not in by                       # 0.5 ms in scene a: no ratio


def test_speedup_brackets_and_bounds():
    def row(kind, sweep, t, e):
        return {"scene": "x", "setting": f"{kind} {sweep}", "integrator": kind, "sweep": sweep,
                "status": "ok", "paper_s": t, "scattering_s": t, "time_s": t, "relmse_b1": e}
    rows = [row("raymarch", 16, 1.0, 1e-2), row("raymarch", 64, 4.0, 1e-4),
            row("epipolar_tree", 100, 0.5, 1e-5)]
    rows.append({"scene": "x", "setting": "filter", "integrator": "fourier_filter",
                 "sweep": None, "status": "ok", "paper_s": 0.1, "scattering_s": 0.1,
                 "time_s": 0.1, "relmse_b1": 1e-3, "dominant_stage": "svd"})
    out = {(r["baseline"], r["convention"]): r for r in fourier_speedup.speedups(rows)}
    rm = out[("raymarch", "paper")]
    assert rm["bound"] == "=" and rm["speedup"] == pytest.approx(20.0)   # sqrt(1*4) / 0.1
    assert rm["baseline_sweep_at_equal_error"] == pytest.approx(32.0)
    assert out[("epipolar_tree", "paper")]["bound"] == "<="


# --------------------------------------------------------------------------
# Quick runs
# --------------------------------------------------------------------------

def test_table2_quick(cache, tmp_path):
    out = tmp_path / "t2"
    rows, kernel = fourier_table2.main(["--quick", "--out", str(out)])
    check_outputs(out, ["table2.csv", "table1_regions.csv", "kernel_regions.csv",
                        "table2.json", "table.md", "table2.png"])
    assert all(r["status"] == "ok" for r in rows)
    for r in rows:
        assert r["prefilter_ms"] > 0 and r["evaluate_ms"] > 0 and r["relmse_b1"] < 0.1
        assert r["texels_built"] == r["texels"]
        assert r["memory_mb_built"] == fourier_table2.memory_mb(r["filtered_rows"],
                                                                r["texels"], r["M"])
    assert [k["regions"] for k in kernel] == [1, 2]
    assert len(read_csv(out / "table2.csv")) == 3


def test_weights_quick(cache, tmp_path):
    out = tmp_path / "w"
    rows = fourier_weights.main(["--quick", "--out", str(out)])
    check_outputs(out, ["weights.csv", "weights.json", "table.md", "weights.png"])
    assert len(rows) == 2 * len(fourier_weights.MODES)
    for r in rows:
        assert r["status"] == "ok"
        assert r["sigma_t"] * r["scene_size_m"] == pytest.approx(r["tau"])
        if r["weights"] == "exact":
            assert r["vs_exact_weights_relmse_norm"] == 0.0
    thick = {r["weights"]: r for r in rows if r["tau"] == 3.0}
    # average visibility ignores transmittance: worse than the reference ray in thick media
    assert thick["average"]["vs_exact_weights_relmse_norm"] > \
        thick["bisectrix"]["vs_exact_weights_relmse_norm"]


def test_scene_independence_quick(cache, tmp_path):
    out = tmp_path / "s"
    rows, summary = fourier_scene_independence.main(["--quick", "--out", str(out)])
    check_outputs(out, ["scenes.csv", "ratios.csv", "scenes.json", "table.md", "scenes.png"])
    status = {(r["scene"], r["setting"]): r["status"] for r in rows}
    assert status[("point_fog", "fixed")] == "ok"          # point lights: Klehm §3.2
    assert status[("nave_offscreen", "fixed")] == "ok" and status[("beam", "auto")] == "ok"
    fixed = [r for r in rows if r["setting"] == "fixed" and r["status"] == "ok"]
    assert all(r["texels"] == 64 for r in fixed)
    assert {r["quantity"] for r in summary} >= {"scattering", "paper", "total"}
    assert all(r["ratio"] >= 1.0 for r in summary)


def test_speedup_quick(cache, tmp_path):
    out = tmp_path / "sp"
    rows, summary = fourier_speedup.main(["--quick", "--out", str(out),
                                          "--scenes", "nave_offscreen", "point_fog"])
    check_outputs(out, ["runs.csv", "speedup.csv", "speedup.json", "table.md", "speedup.png"])
    assert all(r["status"] == "ok" for r in rows)        # point lights too (Klehm §3.2)
    ok = [r for r in rows if r["scene"] == "nave_offscreen"]
    d = ok[0]["shadow_resolution"]
    assert all(r["params"]["shadowmap_resolution"] == d for r in ok
               if r["integrator"] == "raymarch")
    assert len(summary) == 2 * 2 * 2 * 3      # scenes x filters x baselines x conventions
    for r in summary:
        assert r["bound"] in ("=", ">=", "<=") and r["speedup"] > 0 and math.isfinite(r["speedup"])


def test_projective_angles_quick(cache, tmp_path, capsys):
    """Both rectifications at every yaw, the one too close to the axis
    refused by ``projective`` with its reason; a resumed run reads the
    per-yaw checkpoints instead of rendering again."""
    out = tmp_path / "pa"
    rows = projective_angles.main(["--quick", "--out", str(out)])
    check_outputs(out, ["runs.csv", "runs.json", "table.md"])
    assert len(rows) == 2 * 2 * 2              # yaws x rectifications x weights
    near, far = sorted({r["axis_angle_deg"] for r in rows})
    assert near < 5.0 < far                    # the floor of the projective map
    for r in rows:
        if r["rectification"] == "projective" and r["axis_angle_deg"] < 5.0:
            assert "impossible here" in r["status"]
        else:
            assert r["status"] == "ok" and r["rows"] > 0
            assert abs(r["mean_ratio_b1"] - 1) < 0.05 and r["relmse_b1"] < 1e-2
    capsys.readouterr()
    again = projective_angles.main(["--quick", "--out", str(out), "--resume"])
    assert "rows from" in capsys.readouterr().out
    assert [r.get("relmse_b1") for r in again] == [r.get("relmse_b1") for r in rows]
