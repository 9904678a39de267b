"""Frontiers (episcatter.frontier): Pareto logic, log-log interpolation and
its bounds against hand-made data, the settings grids, the errors, and a tiny
end-to-end sweep through the experiment and the CLI."""
import json
import math

import numpy as np
import pytest

from episcatter import frontier as fr
from tests.conftest import read_csv


# --------------------------------------------------------------------------
# Pareto frontier
# --------------------------------------------------------------------------

def test_pareto_front_keeps_the_points_nothing_beats_sorted_by_time():
    pts = [(1.0, 1e-2, "a"), (2.0, 1e-3, "b"), (1.5, 2e-2, "dominated by a"),
           (3.0, 1e-3, "dominated by b (equal error, slower)"), (4.0, 1e-4, "c"),
           (0.5, 5e-2, "fastest")]
    assert [p[2] for p in fr.pareto_front(pts)] == ["fastest", "a", "b", "c"]


def test_pareto_front_ties_in_time_keep_the_lower_error_and_drop_unusable_points():
    pts = [(1.0, 1e-2, "worse"), (1.0, 1e-3, "better"), (2.0, 0.0, "the reference itself"),
           (3.0, math.nan, "nan"), (math.inf, 1e-9, "inf time"), (-1.0, 1e-9, "negative")]
    assert [p[2] for p in fr.pareto_front(pts)] == ["better"]
    assert fr.pareto_front([]) == []


# --------------------------------------------------------------------------
# Time at an error level
# --------------------------------------------------------------------------

POWER_LAW = [(t, 1e-2 * t ** -2.0) for t in (1.0, 2.0, 8.0)]   # error = 1e-2 t^-2


def test_time_at_error_is_exact_for_a_power_law_between_points():
    front = fr.pareto_front(POWER_LAW)
    for level in (1e-2, 5e-3, 1e-3, 2.5e-3, 1e-2 / 64):
        t, bound = fr.time_at_error(front, level)
        assert bound == "="
        assert t == pytest.approx((1e-2 / level) ** 0.5, rel=1e-12)


def test_time_at_error_bounds_and_never_extrapolates():
    front = fr.pareto_front(POWER_LAW)
    assert fr.time_at_error(front, 1e-1) == (1.0, "<=")        # beaten at the fastest point
    assert fr.time_at_error(front, 1e-6) == (8.0, ">=")        # never reached
    t, b = fr.time_at_error([], 1e-3)
    assert math.isnan(t) and b == "?"
    one = [(2.0, 1e-3)]
    assert fr.time_at_error(one, 1e-3) == (2.0, "=")
    assert fr.time_at_error(one, 1e-2) == (2.0, "<=")
    assert fr.time_at_error(one, 1e-4) == (2.0, ">=")
    with pytest.raises(ValueError, match="positive"):
        fr.time_at_error(front, 0.0)


def test_interpolation_is_log_log_not_linear():
    front = [(1.0, 1e-2), (100.0, 1e-4)]
    t, _ = fr.time_at_error(front, 1e-3)
    assert t == pytest.approx(10.0)     # linear interpolation would give ~90


# --------------------------------------------------------------------------
# Speedups and their bounds
# --------------------------------------------------------------------------

BASE = [(1.0, 1e-2), (10.0, 1e-3), (100.0, 1e-4)]     # the marcher: 10x time per decade
FAST = [(0.1, 1e-3), (1.0, 1e-5)]


def test_speedup_at_equal_error_from_both_frontiers():
    s = fr.speedup_at(BASE, FAST, 1e-3)
    assert (s["speedup"], s["bound"]) == (pytest.approx(100.0), "=")
    s = fr.speedup_at(BASE, FAST, 1e-4)     # test: t = 10^-0.5 (log-log midpoint)
    assert s["speedup"] == pytest.approx(100.0 / 10 ** -0.5) and s["bound"] == "="
    assert fr.speedup_text(s) == "316x"


@pytest.mark.parametrize("base, test, level, bound, value", [
    (BASE, FAST, 1e-5, ">=", 100.0),         # base never reaches: base >= 100, test = 1
    (BASE, FAST, 1e-2, ">=", 10.0),          # test already below at its fastest: test <= 0.1
    (FAST, BASE, 1e-5, "<=", 1 / 100.0),     # mirror: the test never reaches it
    (FAST, BASE, 1e-2, "<=", 0.1),           # mirror: base <= 0.1
    ([(1.0, 1e-3)], [(2.0, 1e-3)], 1e-6, "?", 0.5),   # both never reach: unknown
    ([(1.0, 1e-3)], [(2.0, 1e-3)], 1e-1, "?", 0.5),   # both beat it at once: unknown
])
def test_speedup_bounds(base, test, level, bound, value):
    s = fr.speedup_at(fr.pareto_front(base), fr.pareto_front(test), level)
    assert s["bound"] == bound
    assert s["speedup"] == pytest.approx(value)
    assert fr.speedup_text(s).startswith({"=": "", ">=": ">= ", "<=": "<= ", "?": "-"}[bound])


def test_speedup_table_reads_every_method_against_the_baseline_per_scene_and_convention():
    def row(method, t, e, conv="pixel_centre", scene="a.xml", **kw):
        return {"scene": scene, "convention": conv, "method": method, "time_s": t,
                "relmse": e, **kw}
    rows = ([row("raymarch", t, e) for t, e in BASE] + [row("epipolar_tree", t, e) for t, e in FAST]
            + [row("epipolar_tree", 0.01, 1e-9, error_message="failed: x")]     # ignored
            + [row("epipolar_tree", 1.0, 1e-3, conv="antialiased")])            # no baseline there
    table = fr.speedup_table(rows, levels=(1e-3,))
    assert len(table) == 1
    assert table[0]["method"] == "epipolar_tree" and table[0]["speedup"] == pytest.approx(100.0)
    # the scattering-only key falls back to the end-to-end time where a row has none
    assert fr.speedup_table(rows, levels=(1e-3,), time_key="scattering_s")[0]["speedup"] == \
        pytest.approx(100.0)


def test_capture_bound_is_the_marchers_time_at_the_level_over_the_camera_capture():
    from episcatter import frontier_report as rep

    def row(method, t, e, cam, **kw):
        return {"scene": "a.xml", "convention": "pixel_centre", "method": method, "time_s": t,
                "relmse": e, "spp": 1, "camera_capture_s": cam, **kw}
    rows = ([row("raymarch", 1.0, 1e-3, 0.1), row("raymarch", 4.0, 1e-5, 0.1)]
            + [row("epipolar_tree", 0.5, 1e-4, 0.3), row("epipolar_tree", 0.6, 1e-5, 0.2),
               row("epipolar_tree", 0.6, 1e-6, 9.0, spp=4)])    # not a 1-spp capture
    bounds = {b["level"]: b for b in rep.capture_bound_rows(rows, levels=(1e-3, 1e-4, 1e-6))}
    # median of the 1-spp captures (0.1, 0.1, 0.3, 0.2) = 0.15
    assert bounds[1e-3]["camera_capture_s"] == pytest.approx(0.15)
    assert bounds[1e-3]["largest_speedup"] == pytest.approx(1.0 / 0.15)
    assert bounds[1e-4]["raymarch_time_s"] == pytest.approx(2.0)      # log-log midpoint
    assert bounds[1e-4]["bound"] == "="
    assert bounds[1e-6]["bound"] == ">=" and bounds[1e-6]["raymarch_time_s"] == 4.0
    text = rep.markdown_report(rows, [], [], list(bounds.values()))
    assert "largest end-to-end speedup" in text and ">= 26.7x" in text


# --------------------------------------------------------------------------
# Grids, tasks
# --------------------------------------------------------------------------

def test_grid_is_the_cartesian_product():
    assert fr.grid(a=[1, 2], b=["x"]) == [{"a": 1, "b": "x"}, {"a": 2, "b": "x"}]


def test_settings_grids_cover_each_methods_knobs():
    rm = fr.settings_grid("raymarch", "quick", "pixel_centre")
    assert {s["visibility"] for s in rm} == {"shadowmap", "exact"}
    assert len({s.get("shadowmap_resolution") for s in rm if s["visibility"] == "shadowmap"}) >= 2
    tree = fr.settings_grid("epipolar_tree", "full", "pixel_centre")
    assert {"slice_spacing", "light_rays", "prefilter", "slice_interpolation"} <= set(tree[1])
    ff = fr.settings_grid("fourier_filter", "full", "pixel_centre")
    assert {"coefficients", "light_rays", "weights"} <= set(ff[1])
    for method in ("epipolar_tree", "fourier_filter", "minmax_epipolar"):
        for budget in fr.BUDGETS:      # each method's defaults are a frontier point
            assert {} in fr.settings_grid(method, budget, "pixel_centre")
    mm = fr.settings_grid("minmax_epipolar", "full", "pixel_centre")
    assert {s.get("profile") for s in mm} >= {"high_quality", "balanced", "high_performance"}
    assert {s.get("refinement") for s in mm} >= {"depth", "visibility", "inscattering"}
    assert all("spp" not in s for s in fr.settings_grid("minmax_epipolar", "full", "antialiased"))
    for method in ("raymarch", "epipolar_tree", "fourier_filter"):
        assert len({s.get("spp") for s in fr.settings_grid(method, "quick", "antialiased")}) > 1
    assert fr.settings_grid("volpath", "quick", "pixel_centre") == []
    assert fr.settings_grid("volpath", "quick", "antialiased", pixels=160 * 120)
    assert fr.settings_grid("volpath", "quick", "antialiased", pixels=640 * 480) == []


def test_settings_grid_errors_name_the_fix(monkeypatch):
    with pytest.raises(ValueError, match="register_method"):
        fr.settings_grid("no_such_method")
    with pytest.raises(ValueError, match="budget"):
        fr.settings_grid("raymarch", "huge")
    with pytest.raises(ValueError, match="convention"):
        fr.settings_grid("raymarch", "quick", "sideways")
    with pytest.raises(ValueError, match="function"):
        fr.register_method("minmax_epipolar", [{"x": 1}])
    monkeypatch.setitem(fr.GRIDS, "dummy", None)
    fr.register_method("dummy", lambda budget, conv: [{"k": 1}])
    assert fr.settings_grid("dummy") == [{"k": 1}]


def test_tasks_are_plain_data_and_pixel_centre_keeps_one_sample():
    import pickle

    refs = {("s.xml", c): f"/ref/{c}.exr" for c in fr.CONVENTIONS}
    tasks = fr.make_tasks(["s.xml"], ["raymarch", "volpath"], "quick", fr.CONVENTIONS,
                          fr.defines_for("quick"), refs, repeats=3)
    assert pickle.loads(pickle.dumps(tasks)) == tasks
    kinds = [(t["convention"], t["method"]) for t in tasks]
    assert kinds == [("pixel_centre", "raymarch"), ("antialiased", "raymarch"),
                     ("antialiased", "volpath")]       # no pixel-centre volpath
    pc = tasks[0]
    # spp given explicitly: without it mi.render takes the scene's sampler
    # count (64 on the suite's scenes), 64x the work of a pixel-centre image
    assert pc["settings"] and all(s["spp"] == 1 for s in pc["settings"])
    assert all(fr._split_spp(s)[1] == 1 for s in pc["settings"])
    assert pc["defines"]["res_x"] == "640" and tasks[1]["defines"]["res_x"] == "160"


def test_defines_for_overrides_sizes_and_refuses_unknown_budgets():
    d = fr.defines_for("full", {"sigma_t": 0.2}, {"antialiased": (48, 36)})
    assert d("x", "pixel_centre") == {"sigma_t": "0.2", "res_x": "1280", "res_y": "960"}
    assert d("x", "antialiased")["res_x"] == "48"
    with pytest.raises(ValueError, match="budget"):
        fr.defines_for("huge")


def test_capture_times_split_camera_and_visibility():
    c = fr.capture_times({"capture": 0.1, "blockers": 0.3, "scattering": 1.0})
    assert c == pytest.approx({"camera_capture_s": 0.1, "visibility_capture_s": 0.3,
                               "captures_s": 0.4, "scattering_net_s": 0.7})
    assert fr.capture_times({"capture": 0.1, "scattering": 1.0})["visibility_capture_s"] == 0.0


# --------------------------------------------------------------------------
# Errors
# --------------------------------------------------------------------------

def test_image_errors_are_scale_free_and_report_energy_and_peak():
    rng = np.random.default_rng(1)
    ref = rng.uniform(0.0, 1.0, (6, 5, 3))
    img = ref * 1.1
    a, b = fr.image_errors(img, ref), fr.image_errors(1e-3 * img, 1e-3 * ref)
    assert a["relmse"] == pytest.approx(b["relmse"], rel=1e-9)
    assert a["mean_ratio"] == pytest.approx(1.1)
    assert a["max_error_over_peak"] == pytest.approx(0.1 * ref.max() / ref.max(), rel=1e-9)
    img2 = img.copy()
    img2[0, 0, 0] = np.nan
    assert fr.image_errors(img2, ref)["nonfinite"] == 1
    with pytest.raises(ValueError, match="resolution"):
        fr.image_errors(img[:2], ref)


def test_scale_free_noise_of_two_halves():
    m = np.full((4, 4, 3), 2.0)
    assert fr.scale_free_noise(m, m) == 0.0
    # halves m +- d: variance of the mean d^2, over (m^2 + 1e-2 m^2)
    assert fr.scale_free_noise(m + 0.1, m - 0.1) == pytest.approx(0.01 / (4.0 * 1.01))


def test_antialiased_reference_refuses_too_few_rays():
    with pytest.raises(ValueError, match=">= 8"):
        fr.make_reference("unused.xml", {}, "antialiased", spp=4)


# --------------------------------------------------------------------------
# End to end
# --------------------------------------------------------------------------

@pytest.mark.slow
def test_experiment_tiny_run_writes_frontiers_speedups_floor_and_plots(tmp_path, cache):
    from episcatter.reference import load_halves
    from experiments import frontier as exp

    out = tmp_path / "out"
    assert exp.main(["--quick", "--scenes", "point_fog", "--out", str(out),
                     "--methods", "raymarch", "epipolar_tree", "volpath"]) == 0
    rows = read_csv(out / "runs.csv")
    assert {r["method"] for r in rows} == {"raymarch", "epipolar_tree", "volpath"}
    assert not [r for r in rows if r.get("error_message")]
    assert all(float(r["time_s"]) > 0 and float(r["relmse"]) >= 0 for r in rows)
    speedups = read_csv(out / "speedups.csv")
    assert {s["time_key"] for s in speedups} == {"time_s", "scattering_s"}
    assert {float(s["level"]) for s in speedups} == set(fr.LEVELS)
    doc = json.loads((out / "runs.json").read_text())
    assert {"mitsuba", "drjit", "load_average", "OPENBLAS_NUM_THREADS"} <= set(doc["environment"])
    assert doc["settings"]["references"]
    floors = read_csv(out / "floor.csv")
    tree = [f for f in floors if f["method"] == "epipolar_tree"]
    assert tree and all(float(f["captures_s"]) > 0 for f in tree)
    assert (out / "frontier_point_fog.png").stat().st_size > 1000
    assert "Speedup over `raymarch`" in (out / "table.md").read_text()
    assert read_csv(out / "aa_check.csv")[0]["volpath_spp"] == "64"
    # the antialiased reference jitters its rays: its two halves differ
    aa_ref = [p for k, p in doc["settings"]["references"].items() if k.endswith("antialiased")][0]
    a, b = load_halves(aa_ref)
    assert np.abs(a - b).max() > 0
    # merging the sweep's own runs.json reproduces its speedups
    merged = tmp_path / "merged"
    assert exp.main(["--merge", str(out), "--out", str(merged)]) == 0
    assert read_csv(merged / "speedups.csv") == speedups
    assert (merged / "aa_check.csv").is_file()


def cli_sweep(out, scene: str, method: str, *options) -> list[dict]:
    """``episcatter frontier`` of one suite scene and method at tiny sizes,
    one timed repeat; the run rows (the command must succeed)."""
    import scenes
    from episcatter import cli

    status = cli.main(["frontier", scenes.path(scene), "-i", method, *options,
                       "--repeats", "1", "--no-progress", "-o", str(out)])
    assert status == 0
    return read_csv(out / "runs.csv")


@pytest.mark.slow
def test_cli_frontier_one_method_one_convention(tmp_path, cache, capsys):
    rows = cli_sweep(tmp_path / "cli", "nave_offscreen", "fourier_filter",
                     "--convention", "pixel_centre", "--size", "24x16")
    assert len(rows) == len(fr.settings_grid("fourier_filter", "quick", "pixel_centre"))
    assert {r["width"] for r in rows} == {"24"}
    assert "Captures" in capsys.readouterr().out


def test_minmax_epipolar_is_swept_in_both_conventions(tmp_path, cache):
    """minmax_epipolar sits on the frontiers like the other methods (it was
    not registered: every sweep left it out); its antialiased points render
    one sample per pixel centre, as the method requires."""
    rows = cli_sweep(tmp_path / "mm", "spot_room", "minmax_epipolar",
                     "--size", "24x16", "--aa-size", "16x12")
    assert not [r for r in rows if r.get("error_message")]
    for conv in fr.CONVENTIONS:
        got = [r for r in rows if r["convention"] == conv]
        assert len(got) == len(fr.settings_grid("minmax_epipolar", "quick", conv))
        assert all(float(r["relmse"]) >= 0 and float(r["time_s"]) > 0 for r in got)


def test_cli_frontier_rejects_a_bad_size(capsys):
    from episcatter import cli

    assert cli.main(["frontier", "x.xml", "--size", "640by480"]) == 2
    assert "WIDTHxHEIGHT" in capsys.readouterr().err


# --------------------------------------------------------------------------
# Error budget
# --------------------------------------------------------------------------

def test_settings_for_budget_refuses_unknown_methods_and_bad_budgets():
    with pytest.raises(ValueError, match="rule"):
        fr.settings_for_budget(None, "volpath", 1e-4)
    with pytest.raises(ValueError, match="positive"):
        fr.settings_for_budget(None, "epipolar_tree", 0.0)


def test_report_json_is_strict_and_keeps_strings():
    from episcatter.frontier_report import _plain

    doc = _plain({"a": math.nan, "b": [np.float32(1.5), np.int64(3), math.inf],
                  "c": "NaN in a message", "d": (1, 2)})
    assert doc == {"a": None, "b": [1.5, 3, None], "c": "NaN in a message", "d": [1, 2]}
    json.dumps(doc, allow_nan=False)
