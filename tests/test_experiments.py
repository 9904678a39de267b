"""The experiment scripts: helpers, and each ``--quick`` mode end to end
(tiny images, their own reference cache in a temporary folder)."""
import json
import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from experiments import common, stability, tree_accuracy, tree_scaling, tree_speedup
from tests.conftest import read_csv


def check_outputs(folder, names):
    """Every file exists, is small, and the JSON carries settings and environment."""
    for name in names:
        path = folder / name
        assert path.is_file(), name
        assert path.stat().st_size < 500_000, name
    for name in names:
        if name.endswith(".json"):
            doc = json.loads((folder / name).read_text())
            assert doc["settings"] and doc["environment"]["drjit_threads"] >= 1


# --------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------

def test_equal_error_time_interpolates_log_log():
    curve = [(1.0, 1e-2), (4.0, 1e-4), (16.0, 1e-6)]
    t, bound = tree_speedup.equal_error_time(curve, 1e-3)
    assert bound == "=" and t == pytest.approx(2.0)
    assert tree_speedup.equal_error_time(curve, 1e-7) == (16.0, ">=")
    assert tree_speedup.equal_error_time(curve, 1e-1) == (1.0, "<=")
    # a plateau that rises again: the first crossing counts
    t, bound = tree_speedup.equal_error_time([(1, 1e-2), (2, 1e-3), (4, 2e-3)], 1e-3)
    assert (t, bound) == (2, "=")
    assert math.isnan(tree_speedup.equal_error_time([], 1e-3)[0])


def test_slope_of_power_law():
    x = [1.0, 2.0, 4.0, 8.0]
    assert tree_scaling.slope(x, [v ** 2.5 for v in x]) == pytest.approx(2.5)
    assert math.isnan(tree_scaling.slope([1.0], [1.0]))


def test_errors_flatten_blocks():
    rng = np.random.default_rng(0)
    ref = rng.random((8, 8, 3)) + 0.5
    e = common.errors(ref * 1.01, ref)
    assert e["nonfinite"] == 0 and e["relmse_b1"] > e["relmse_b2"] * 0.5
    assert set(e) >= {"relmse_b1", "flip_b1", "relmse_b2", "flip_b2"}
    bad = ref.copy()
    bad[0, 0, 0] = np.nan
    assert common.errors(bad, ref)["nonfinite"] == 1


def test_limit_blas_threads_restores():
    before = common.blas_threads()
    with common.limit_blas_threads(1):
        assert common.blas_threads() in (None, 1)
    assert common.blas_threads() == before


def test_describe_error_marks_unsupported():
    exc = RuntimeError("wrapper")
    exc.__cause__ = ValueError("only directional lights are supported")
    assert common.describe_error(exc).startswith("not supported yet")
    assert common.describe_error(KeyError("x")).startswith("failed")


def test_stress_scene_scales_every_length():
    import mitsuba as mi

    d = stability.stress_scene(stability.point([0.3, 2.0, 0.4]), scale=100.0)
    assert d["light"]["position"] == pytest.approx([30.0, 200.0, 40.0])
    assert d["blocker"]["radius"] == 40.0 and d["sensor"]["near_clip"] == 1.0
    scene = mi.load_dict(d)
    assert scene.bbox().max.x == pytest.approx(400.0, rel=1e-5)


def test_epipole_on_pixel_centre_is_on_pixel_centre():
    """The directional light of the first case points back along the ray
    through that pixel's centre."""
    from rectify.describe import describe

    from integrators.core.scene_params import SceneParams
    import mitsuba as mi

    res = (64, 48)
    case = stability.epipole_cases(res)[0]
    scene = mi.load_dict(stability.stress_scene(case["light"], res=res))
    params = SceneParams.from_scene(scene)
    info = describe(params.camera, ("directional", params.light.direction))
    assert info["epipole_px"] == pytest.approx([20.5, 14.5], abs=1e-3)


# --------------------------------------------------------------------------
# --quick runs
# --------------------------------------------------------------------------

def test_tree_accuracy_quick(tmp_path, cache):
    rows = tree_accuracy.main(["--quick", "--out", str(tmp_path)])
    check_outputs(tmp_path, ["accuracy.csv", "accuracy.json", "table.md", "accuracy.png",
                             "error_maps.png"])
    assert {r["method"] for r in rows} == {m[0] for m in tree_accuracy.METHODS}
    tree = next(r for r in rows if r["method"] == "epipolar_tree")
    assert tree["status"] == "ok" and tree["nonfinite"] == 0 and tree["relmse_b1"] < 0.05
    assert "| epipolar_tree |" in (tmp_path / "table.md").read_text()


def test_tree_speedup_quick(tmp_path, cache):
    rows, summary = tree_speedup.main(["--quick", "--out", str(tmp_path)])
    check_outputs(tmp_path, ["runs.csv", "speedup.csv", "speedup.json", "table.md",
                             "speedup.png"])
    assert all(r["status"] == "ok" for r in rows)
    trees = [k for k in tree_speedup.settings_of_run(tree_speedup.settings_for(True))
             if k.startswith("tree")]
    assert len(summary) == (len(trees) * len(tree_speedup.BASELINES)
                            * len(tree_speedup.CONVENTIONS))
    for s in summary:
        assert s["bound"] in ("=", ">=", "<=") and s["speedup"] > 0
    assert len(read_csv(tmp_path / "runs.csv")) == len(rows)


def test_tree_scaling_quick(tmp_path, cache):
    rows, slopes = tree_scaling.main(["--quick", "--out", str(tmp_path)])
    check_outputs(tmp_path, ["scaling.csv", "slopes.csv", "scaling.json", "table.md",
                             "scaling.png"])
    fitted = {s["method"]: s for s in slopes if s["series"] == "fitted time"}
    assert set(fitted) == {"epipolar_tree", "raymarch"}
    assert all(math.isfinite(s["slope_all"]) for s in fitted.values())


def test_stability_quick(tmp_path, cache):
    rows = stability.main(["--quick", "--out", str(tmp_path)])
    check_outputs(tmp_path, ["stability.csv", "stability.json", "table.md", "stability.png"])
    tree = [r for r in rows if r["method"] == "epipolar_tree"]
    assert tree and all(r["status"] == "ok" for r in tree)
    # the scaled scene with the optical depth kept looks the same as at scale 1
    same = [r for r in tree if r["group"] == "scale, optical depth fixed" and r["scale"] != 1]
    assert same and all(r["ref_relmse_vs_scale1"] < 1e-3 for r in same)


def test_spot_texture_cost_quick(tmp_path):
    from experiments import spot_texture_cost
    spot_texture_cost.main(["--quick", "--out", str(tmp_path)])
    check_outputs(tmp_path, ["cost.csv", "cost.json", "table.md"])
    rows = read_csv(tmp_path / "cost.csv")
    assert {r["light"] for r in rows} == {"textured", "untextured"}
    assert all(float(r["textured_over_untextured"]) > 0 for r in rows)


def test_stability_criteria_check_the_energy():
    """Issue 10: an image at 0.44 of the right brightness must not count as
    bounded (its absolute-eps relMSE was tiny)."""
    rng = np.random.default_rng(3)
    ref = 0.005 + 0.045 * rng.random((12, 16, 3))
    dark = stability.stats(ref * 0.44, ref)
    assert not dark["bounded"] and dark["mean_ratio"] == pytest.approx(0.44)
    assert stability.stats(ref * 1.001, ref)["bounded"]
    assert not stability.bounded(0, 0.0, 0.0, 1.0, mean_ratio=0.8)
    assert stability.bounded(0, 0.0, 0.0, 0.0, mean_ratio=float("nan"))


def test_size_option_replaces_an_experiments_image_size(tmp_path):
    """``--size WxH`` of every experiment (e.g. the minmax tables at
    1280x960): width/height replaced, a bad size named, an experiment
    without one image size refuses it."""
    from experiments import common as c
    from experiments import minmax_tree_gain as tg

    assert c.sized({"width": 320, "height": 240, "x": 1}, "1280x960") == {
        "width": 1280, "height": 960, "x": 1}
    assert c.sized({"width": 320, "height": 240}, None) == {"width": 320, "height": 240}
    with pytest.raises(ValueError, match="WIDTHxHEIGHT"):
        c.sized({"width": 1, "height": 1}, "1280by960")
    with pytest.raises(ValueError, match="no single image size"):
        c.sized({"sizes": []}, "64x48")
    run = c.start_run(tg, ["--size", "40x30", "--out", str(tmp_path)], tg.SCENES, tg.QUICK_SCENES)
    assert (run.settings["width"], run.settings["height"]) == (40, 30)


def test_reference_convergence_runs_without_a_cached_reference(capsys, tmp_path, monkeypatch):
    """experiments.reference_convergence renders what it compares (it used to
    make the suite's cached reference first, which no row read)."""
    import json

    from experiments import reference_convergence as rc

    monkeypatch.setenv("EPISCATTER_CACHE", str(tmp_path))
    rc.main(["8", "6", "beam", "--bisected-convergence"])
    row = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert row["relmse_bisected_2048x12"] < row["relmse_midpoint_2048"]
    assert not any(tmp_path.iterdir())


def test_minmax_bounded_quick(tmp_path, cache):
    from experiments import minmax_bounded
    rows = minmax_bounded.main(["--quick", "--out", str(tmp_path)])
    check_outputs(tmp_path, ["runs.csv", "runs.json", "table.md"])
    assert {r["method"] for r in rows} == {"epipolar_tree", "minmax_epipolar"}
    assert all(r["status"] == "ok" and r["warm_s"] > 0 for r in rows)
    tree, mm = (next(r for r in rows if r["method"] == m)
                for m in ("epipolar_tree", "minmax_epipolar"))
    assert minmax_bounded.bounded(tree, {**mm, "relmse": 9 * tree["relmse"]}) == (
        abs(mm["mean_ratio"] - 1) <= minmax_bounded.MEAN_TOL)
    assert not minmax_bounded.bounded(tree, {**mm, "relmse": 11 * tree["relmse"] + 1e-6})


def test_fourier_spot_quick(tmp_path, cache):
    from experiments import fourier_spot
    rows = fourier_spot.main(["--quick", "--out", str(tmp_path)])
    check_outputs(tmp_path, ["runs.csv", "runs.json", "table.md"])
    assert [r["setting"] for r in rows] == list(fourier_spot.SETTINGS)
    assert all(r["status"] == "ok" and r["peak_mb"] >= r["base_mb"] > 0 for r in rows)


def test_launches_quick(tmp_path):
    from experiments import launches
    rows = launches.main(["--quick", "--out", str(tmp_path)])
    check_outputs(tmp_path, ["runs.csv", "runs.json", "table.md"])
    assert {r["method"] for r in rows} == set(launches.METHODS)
    assert all(r["launched"] >= r["distinct"] > 0 and r["compiled"] == 0 for r in rows)


def test_capture_floor_quick(tmp_path):
    from experiments import capture_floor
    rows = capture_floor.main(["--quick", "--out", str(tmp_path)])
    check_outputs(tmp_path, ["runs.csv", "runs.json", "table.md"])
    (row,) = rows
    assert row["captures_s"] > 0 and row["net_over_captures"] == pytest.approx(
        row["scattering_net_s"] / row["captures_s"])
    assert row["first_s"] > 0 and row["new_frame_s"] > 0 and row["warm_s"] > 0


def test_light_cost_quick(tmp_path):
    from experiments import light_cost
    rows = light_cost.main(["--quick", "--methods", "raymarch", "epipolar_tree",
                            "--out", str(tmp_path)])
    check_outputs(tmp_path, ["runs.csv", "runs.json", "table.md"])
    assert [(r["method"], r["lights"]) for r in rows] == [
        ("raymarch", 1), ("raymarch", 2), ("epipolar_tree", 1), ("epipolar_tree", 2)]
    assert all(len(r["single_scattering_s"]) == r["lights"] and r["bound_s"] > 0 for r in rows)


def test_light_cost_variants_keep_the_chosen_emitters():
    from experiments.light_cost import variant_text
    text = ('<scene version="3.0.0"><emitter type="point" id="a"/><shape type="cube"/>'
            '<emitter type="spot" id="b"/><emitter type="directional" id="c"/></scene>')
    assert [e.get("id") for e in ET.fromstring(variant_text(text, {0, 2}))
            if e.tag == "emitter"] == ["a", "c"]
    assert len(ET.fromstring(variant_text(text, {1}))) == 2          # the cube stays


def test_auto_suite_small(tmp_path):
    from experiments import auto_suite
    rows = auto_suite.main(["--method", "raymarch", "--scenes", "point_fog", "--size", "32x24",
                            "--budgets", "1e-3", "--out", str(tmp_path)])
    check_outputs(tmp_path, ["runs.csv", "runs.json", "table.md"])
    (row,) = rows
    assert row["settings"]["visibility"] == "exact" and row["relmse"] >= 0


def test_probe_strata_small(tmp_path):
    """The probe-pixel experiment on one tiny held-out scene: every
    estimate (strided, both strata, the probe's own) written and finite."""
    from experiments import probe_strata

    rows, out = common.held_out_main(probe_strata.__doc__, (2000,), tmp_path, probe_strata.run,
                                     probe_strata.table, ["--size", "48x36"])
    assert len(rows) == len(probe_strata.SETTINGS)
    for r in rows:
        assert all(math.isfinite(r[k]) and r[k] >= 0 for k, _ in probe_strata.ESTIMATES)
    assert "the probe's stratum against its references" in (out / "table.md").read_text()


def test_error_budget_quick(tmp_path):
    """The held-out evaluation on one tiny scene, one method, without the
    probe-estimate table: every case has its medians, the probe's
    reference time and the bound of a rule that rendered only the best
    setting; the reference cache serves the second run."""
    from experiments import error_budget

    cache = tmp_path / "refs"
    args = ["--quick", "--methods", "minmax_epipolar", "--no-probe-accuracy",
            "--reference-cache", str(cache)]
    error_budget.main(args + ["--out", str(tmp_path / "a")])
    check_outputs(tmp_path / "a", ["choices.csv", "sweep.csv", "budget.json", "table.md"])
    assert not (tmp_path / "a" / "probe.csv").exists()
    rows = read_csv(tmp_path / "a" / "choices.csv")
    assert len(rows) == len(error_budget.LEVELS)
    for r in rows:
        t_meet, t_ref = float(r["best_meeting_time_s"]), float(r["probe_reference_s"])
        assert t_ref > 0 and float(r["time_with_probe_s"]) > 0
        if math.isfinite(t_meet):
            assert float(r["oracle_over_best_meeting"]) == pytest.approx((t_meet + t_ref) / t_meet)
    cached = sorted(cache.iterdir())
    assert cached
    error_budget.main(args + ["--out", str(tmp_path / "b")])
    assert sorted(cache.iterdir()) == cached
    assert "best + probe reference <= 2x best" in (tmp_path / "b" / "table.md").read_text()
    # merged: the later run's rows replace the earlier's for the same scene
    # and method, and the table is that of either run
    error_budget.main(["--merge", str(tmp_path / "a"), str(tmp_path / "b"),
                       "--out", str(tmp_path / "m")])
    merged = read_csv(tmp_path / "m" / "choices.csv")
    assert merged == read_csv(tmp_path / "b" / "choices.csv")
    table = lambda d: (tmp_path / d / "table.md").read_text().split("\n", 1)[1]
    assert table("m").split("fitted constants")[0] == table("b").split("fitted constants")[0]
    seed = error_budget.scene_seed(merged[0]["scene"])
    with pytest.raises(ValueError, match="lower --first-seed"):
        error_budget.merge_runs([tmp_path / "a"], tmp_path / "n", "", first_seed=seed + 1)
    with pytest.raises(ValueError, match="no choices.csv rows"):    # another method's only
        error_budget.merge_runs([tmp_path / "a"], tmp_path / "n", "", methods=("raymarch",))


def test_error_budget_sweeps_the_marcher_as_far_as_asked(tmp_path):
    """``--march-steps``: the marcher's swept step counts (a budget no count
    of the default sweep reaches is reachable with more steps); the run
    records them; the module's default sweep is unchanged."""
    from experiments import error_budget

    assert error_budget.march_sweep([1024, 16, 16, 64]) == [
        {"visibility": "exact", "steps": n} for n in (16, 64, 1024)]
    default = list(error_budget.SWEEPS["raymarch"])
    error_budget.main(["--quick", "--methods", "raymarch", "--no-probe-accuracy",
                       "--march-steps", "16", "48", "--out", str(tmp_path / "r")])
    swept = {json.loads(r["settings"])["steps"] for r in read_csv(tmp_path / "r" / "sweep.csv")}
    assert swept == {16, 48}
    settings = json.loads((tmp_path / "r" / "budget.json").read_text())["settings"]
    assert settings["march_steps"] == [16, 48]
    assert error_budget.SWEEPS["raymarch"] == default
