"""The command line as a user meets it (issue 10, defects 3, 4, 5, 7):
like-for-like checks, warm and first-run times, traps refused early."""
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from episcatter import cli, cmd_render
from episcatter.imageio import read_exr

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENE = os.path.join(ROOT, "tests", "data", "tiny_scene.xml")
TINY = ["-D", "res_x=16", "-D", "res_y=12", "-D", "spp=1"]
FAST = ["-i", "raymarch", "-p", "steps=8", "-p", "visibility=exact"]


@pytest.fixture
def no_render(monkeypatch):
    """Fail the test if a render starts."""
    def refuse(*args, **kwargs):
        raise AssertionError("rendered although the arguments were bad")
    monkeypatch.setattr(cmd_render, "timed_runs", refuse)


def run_cli(argv, capsys):
    code = cli.main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_cli_pins_openblas_to_one_thread_before_numpy_loads():
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    code = ("import episcatter.cli, numpy, sys; from episcatter.blas import blas_threads; "
            "print(blas_threads(), 'numpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, text=True,
                         capture_output=True, check=True).stdout.split()
    assert out[1] == "True" and out[0] in ("1", "None"), out


def test_png_output_writes_exr_and_png(cache, tmp_path, capsys):
    code, out, err = run_cli(["render", SCENE, *FAST, *TINY, "-o", str(tmp_path / "x.png"),
                              "--check", "none", "--repeats", "0"], capsys)
    assert code == 0, err
    assert (tmp_path / "x.exr").stat().st_size > 0 and (tmp_path / "x.png").stat().st_size > 0
    assert "full" in read_exr(tmp_path / "x.exr")
    assert f"wrote {tmp_path / 'x.exr'} and {tmp_path / 'x.png'}" in out


@pytest.mark.parametrize("argv, message", [
    (["--spp", "-3"], "--spp -3"),
    (["--eps", "0"], "must be a finite number > 0"),
    (["-o", "nodir/x.exr"], "does not exist"),
    (["-o", "x.jpg"], "must end in .exr or .png"),
])
def test_bad_arguments_fail_before_rendering(cache, tmp_path, capsys, no_render, argv, message):
    if argv[0] == "-o":
        argv = ["-o", str(tmp_path / argv[1])]
    code, _, err = run_cli(["render", SCENE, *FAST, *TINY, *argv], capsys)
    assert code == 2 and message in err, err


def test_compare_refuses_eps_zero(tmp_path, capsys):
    from episcatter.imageio import write_exr
    write_exr(tmp_path / "a.exr", np.ones((2, 2, 3), np.float32))
    code, _, err = run_cli(["compare", str(tmp_path / "a.exr"), str(tmp_path / "a.exr"),
                            "--eps", "0"], capsys)
    assert code == 2 and "must be a finite number > 0" in err


def test_scene_without_integrator_needs_dash_i(tmp_path, capsys, no_render):
    text = open(SCENE).read()
    text = re.sub(r"<integrator.*?</integrator>", "", text, flags=re.S)
    path = tmp_path / "no_integrator.xml"
    path.write_text(text)
    code, _, err = run_cli(["render", str(path), *TINY], capsys)
    assert code == 2 and "has no <integrator>: pass one with -i TYPE" in err


def test_zero_sigma_t_channel_is_refused_for_volpath(tmp_path, capsys, no_render):
    text = open(SCENE).read().replace('<float name="sigma_t" value="$sigma_t"/>',
                                      '<rgb name="sigma_t" value="0.15, 0, 0.15"/>')
    path = tmp_path / "zero_channel.xml"
    path.write_text(text)
    code, _, err = run_cli(["render", str(path), "-i", "volpath", *TINY], capsys)
    assert code == 2 and "zero in some channels" in err and "NaN" in err


def numbers(pattern, text):
    return [float(x) for x in re.findall(pattern, text)]


def test_render_reports_first_and_warm_times_and_stages_sum(cache, tmp_path, capsys):
    code, out, err = run_cli(["render", SCENE, *FAST, *TINY, "-o", str(tmp_path / "r.exr"),
                              "--check", "none", "--repeats", "2"], capsys)
    assert code == 0, err
    assert "first run" in out and "kernel compilation" in out
    assert "warm" in out and "median of 2 run(s)" in out
    line = next(s for s in out.splitlines() if "stages of the median warm run" in s)
    parts = numbers(r"\b[a-z]+ (\d+\.\d+)", line.split(":", 1)[1].split("=")[0])
    total = float(line.rsplit("=", 1)[1].split()[0])
    assert "other" in line and abs(sum(parts) - total) <= 0.004, line


def test_render_check_is_like_for_like(cache, tmp_path, capsys):
    code, out, err = run_cli(["render", SCENE, *FAST, *TINY, "-o", str(tmp_path / "c.exr"),
                              "--repeats", "0"], capsys)
    assert code == 0, err
    assert "1 spp, pixel centres" in out
    assert "pixel centres vs pixel centres (like for like)" in out
    assert "scale-free relMSE" in out and "mean ratio" in out and "max error / peak" in out
    # antialiased (4 spp): the pixel-centre reference is not used
    code, out, err = run_cli(["render", SCENE, *FAST, *TINY, "--spp", "4", "-o",
                              str(tmp_path / "d.exr"), "--repeats", "0"], capsys)
    assert code == 0, err
    assert "4 spp, antialiased" in out and "pixel centres vs" not in out


def test_epipolar_png_draws_slices_epipole_and_ring(tmp_path, capsys):
    png = tmp_path / "geometry.png"
    code, out, err = run_cli(["epipolar", os.path.join(ROOT, "scenes", "point_fog.xml"),
                              "-D", "res_x=40", "-D", "res_y=30", "--png", str(png),
                              "--lines", "12", "--json"], capsys)
    assert code == 0, err
    import json
    drawing = json.loads(out)["drawing"]
    assert drawing["lines"] == 12 and drawing["slices"] > 12
    assert drawing["epipole_marked"] and drawing["ring_pixels"] > 0
    assert png.stat().st_size > 5000
    code, _, err = run_cli(["epipolar", SCENE, "--png", str(tmp_path / "x.exr")], capsys)
    assert code == 2 and "must end in .png" in err


def test_render_with_an_error_budget_says_what_it_chose(capsys, tmp_path):
    """``quality=auto``: the settings the rule chose, the relMSE it expects
    (and whether the probe measured it or its model predicts it) and the
    probe's cost are printed, not only recorded."""
    code, out, _ = run_cli(["render", SCENE, *TINY, "-i", "epipolar_tree", "-p", "quality=auto",
                            "-p", "error_budget=1e-3", "--repeats", "0",
                            "-o", str(tmp_path / "auto.exr")], capsys)
    assert code == 0
    assert re.search(r"quality=auto chose slice_spacing=\S+, light_rays=\d+ for error_budget "
                     r"0\.001", out), out
    assert re.search(r"expected relMSE \d\.\d\de-\d\d \((measured by the probe|predicted)", out)
    assert re.search(r"probe: \d+\.\d+ s on \d+ pixels", out)
