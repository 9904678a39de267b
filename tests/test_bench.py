"""Tests of episcatter.bench and the `bench` subcommand (tiny renders)."""

import argparse
import csv
import json
import math
import os

import pytest

from episcatter import bench, cmd_bench, reference

SCENE = os.path.join(os.path.dirname(__file__), "data", "tiny_scene.xml")
TINY = {"res_x": 16, "res_y": 12}
FAST = {"raymarch.shadowmap_resolution": 64}


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("EPISCATTER_CACHE", str(folder))
    return folder


@pytest.fixture
def ref_path(cache):
    _, info = reference.render_reference(SCENE, TINY, spp=64, chunk=32, progress=False)
    return info["path"]


def test_params_for_scopes_by_type():
    p = {"steps": 8, "raymarch.steps": 16, "volpath.max_depth": 2, "output": "full"}
    assert bench.params_for("raymarch", p) == {"steps": 16, "output": "full"}
    assert bench.params_for("volpath", p) == {"steps": 8, "max_depth": 2, "output": "full"}


def test_expand_jobs_cartesian_product():
    sweeps = {"raymarch.steps": [8, 16], "raymarch.visibility": ["shadowmap", "exact"],
              "volpath.spp": [1, 2, 4]}
    jobs = bench.expand_jobs([SCENE], ["raymarch", "volpath"], FAST, sweeps)
    assert len(jobs) == 4 + 3
    ray = [j["params"] for j in jobs if j["integrator"] == "raymarch"]
    assert {(p["steps"], p["visibility"]) for p in ray} == {
        (8, "shadowmap"), (8, "exact"), (16, "shadowmap"), (16, "exact")}
    assert all(p["shadowmap_resolution"] == 64 for p in ray)
    vol = [j["params"] for j in jobs if j["integrator"] == "volpath"]
    assert vol == [{"spp": 1}, {"spp": 2}, {"spp": 4}]
    with pytest.raises(ValueError, match="not among"):
        bench.expand_jobs([SCENE], ["raymarch"], {"rayamrch.steps": 3}, {})


def test_bench_job_raymarch_times_and_metrics(ref_path):
    res = bench.bench_job(SCENE, "raymarch", {"steps": 16, "shadowmap_resolution": 64},
                          TINY, ref_path, repeats=2, block=2)
    assert (res["width"], res["height"]) == (16, 12)
    assert len(res["times_s"]) == 2 and res["time_s"] > 0 and res["first_run_s"] > 0
    for stage in ("capture", "scattering", "shadowmap", "total"):
        assert res["stages"][stage] > 0, stage
    assert 0 < res["scattering_net_s"] <= res["scattering_s"]
    assert res["block"] == 2 and res["compared_shape"] == [6, 8, 3]
    for key in bench.METRIC_KEYS:
        assert math.isfinite(res[key]), key
    assert 0.5 < res["mean_ratio"] < 1.5
    assert res["reference_kind"] == "volpath" and res["reference_noise"] > 0


def test_bench_job_volpath_end_to_end_only(ref_path):
    res = bench.bench_job(SCENE, "volpath", {"spp": 4}, TINY, ref_path, repeats=1)
    assert res["spp"] == 4 and res["params"] == {}
    assert res["stages"] == {} and math.isnan(res["scattering_s"])
    assert res["time_s"] > 0 and res["relmse"] > 0


def test_bench_job_without_reference_and_bad_property():
    res = bench.bench_job(SCENE, "raymarch", {"steps": 4, "visibility": "exact"}, TINY, None,
                          repeats=1)
    assert "relmse" not in res and res["time_s"] > 0
    with pytest.raises(Exception, match="steps"):
        bench.bench_job(SCENE, "raymarch", {"steps": -1}, TINY, None, repeats=1)


def test_run_bench_writes_csv_json_png(cache, tmp_path):
    out = tmp_path / "bench" / "tiny"
    sweeps = {"raymarch.steps": [4, 16], "raymarch.visibility": ["shadowmap", "exact"]}
    results = bench.run_bench([SCENE], ["raymarch"], sweeps=sweeps, defines=TINY,
                              reference="volpath", ref_spp=32, ref_chunk=16,
                              out_dir=str(out), repeats=1, params=FAST, progress=False)
    assert len(results) == 4 and not any(r.get("error") for r in results)
    with open(out / "bench.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4
    assert {(r["param:steps"], r["param:visibility"]) for r in rows} == {
        ("4", "shadowmap"), ("4", "exact"), ("16", "shadowmap"), ("16", "exact")}
    for col in ("time_s", "first_run_s", "scattering_s", "stage_capture_s", "relmse", "flip"):
        assert all(float(r[col]) > 0 for r in rows), col
    assert all(r["stage_shadowmap_s"] == "" for r in rows if r["param:visibility"] == "exact")
    doc = json.loads((out / "bench.json").read_text())
    assert doc["settings"]["sweeps"] == {k: list(v) for k, v in sweeps.items()}
    assert doc["settings"]["reference"] == "volpath" and doc["settings"]["defines"] == {
        "res_x": "16", "res_y": "12"}
    for key in ("mitsuba", "drjit", "cpu_count", "date"):
        assert key in doc["environment"]
    assert len(doc["jobs"]) == 4
    assert (out / "bench.png").stat().st_size > 1000


def test_cli_bench_records_failures(cache, tmp_path, capsys):
    parser = argparse.ArgumentParser()
    cmd_bench.add_arguments(parser)
    out = tmp_path / "b"
    args = parser.parse_args([SCENE, "-i", "raymarch", "--sweep", "raymarch.steps=4,0",
                              "-p", "raymarch.shadowmap_resolution=64", "-D", "res_x=16",
                              "-D", "res_y=12", "--reference", "none", "--repeats", "1",
                              "--out", str(out), "--no-progress"])
    assert cmd_bench.run(args) == 1  # steps=0 is refused by raymarch
    text = capsys.readouterr().out
    assert "steps" in text and "raymarch" in text
    with open(out / "bench.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["error"] == "" for r in rows] == [True, False]


def test_pareto_front():
    pts = [(3, 1.0), (1, 5.0), (2, 6.0), (4, 0.5), (5, 0.7)]
    assert bench.pareto_front(pts) == [(1, 5.0), (3, 1.0), (4, 0.5)]


def test_parse_sweeps():
    assert cmd_bench.parse_sweeps(["steps=16,64", "visibility=exact"]) == {
        "steps": [16, 64], "visibility": ["exact"]}
    with pytest.raises(ValueError):
        cmd_bench.parse_sweeps(["steps"])


def test_default_exact_reference_matches_each_jobs_pixel_convention(cache, tmp_path):
    """Issue 10, defect 3: a 1-spp render against a box-filtered reference
    measured aliasing; now 1-spp jobs meet the pixel-centre reference and
    antialiased jobs an antialiased one."""
    results = bench.run_bench([SCENE], ["raymarch"], sweeps={"spp": [1, 4]},
                              defines=TINY, reference="exact", ref_steps=16,
                              params={"steps": 8, "visibility": "exact"},
                              out_dir=str(tmp_path / "b"), repeats=1, progress=False)
    by_spp = {r["spp"]: r for r in results}
    assert by_spp[1]["convention"] == by_spp[1]["reference_convention"] == "pixel centres"
    assert by_spp[4]["convention"] == by_spp[4]["reference_convention"] == "antialiased"
    assert all("like for like" in r["comparison"] for r in results)
    assert by_spp[1]["reference_spp"] == 2 and by_spp[4]["reference_spp"] > 2
    assert "centres/centres" in bench.format_table(results)
    # a fixed reference is used for every job and the mismatch is said
    fixed = bench.run_bench([SCENE], ["raymarch"], sweeps={"spp": [1]}, defines=TINY,
                            reference="exact", ref_steps=16, ref_spp=4, ref_chunk=2,
                            params={"steps": 8, "visibility": "exact"},
                            out_dir=str(tmp_path / "c"), repeats=1, progress=False)
    assert fixed[0]["comparison"].startswith("MISMATCH")
    assert "centres/aa !" in bench.format_table(fixed)


def test_net_scattering_is_never_negative():
    """bench.json had negative scattering_net_s: every sub-stage was
    subtracted from the scattering stage's median."""
    runs = [{"scattering": 0.10, "shadowmap": 0.04, "rectify": 0.05, "sweep": 0.04,
             "ring": 0.02}, {"scattering": 0.12, "shadowmap": 0.05, "rectify": 0.07,
                             "sweep": 0.03, "ring": 0.01}]
    assert bench.median_net_scattering(runs) == pytest.approx(0.065)
    assert bench.net_scattering({"scattering": 0.1}) == 0.1


def test_stage_breakdown_sums_to_the_wall_time():
    top, parts = bench.stage_breakdown({"validate": 0.01, "capture": 0.02, "scattering": 0.2,
                                        "compose": 0.01, "total": 0.245, "svd": 0.1}, 0.25)
    assert list(top) == ["validate", "capture", "scattering", "compose", "other", "total"]
    assert top["other"] == pytest.approx(0.01) and top["total"] == pytest.approx(0.25)
    assert sum(v for k, v in top.items() if k != "total") == pytest.approx(top["total"])
    assert parts == {"svd": 0.1}


def test_plot_has_tick_labels_and_labelled_points():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    results = [{"scene": "s", "integrator": "raymarch", "params": {"steps": n}, "spp": 1,
                "time_s": 0.1 + 0.01 * i, "relmse": 1e-4 * (1 + 0.2 * i)}
               for i, n in enumerate((16, 32, 64))]
    fig, ax = plt.subplots()
    bench.draw_plot(ax, results, {"name": "t", "reference": "exact", "eps": 0.01, "block": 1})
    fig.canvas.draw()
    for axis in (ax.xaxis, ax.yaxis):
        labels = [t.get_text() for t in axis.get_ticklabels() if t.get_visible()]
        lo, hi = axis.get_view_interval()
        shown = [t for t, loc in zip(labels, axis.get_majorticklocs()) if lo <= loc <= hi]
        assert len([t for t in shown if t]) >= 2, labels
    assert sorted(t.get_text() for t in ax.texts) == ["steps=16", "steps=32", "steps=64"]
    plt.close(fig)
