"""Tests of episcatter.metrics and the `compare` subcommand."""

import argparse
import json

import numpy as np
import pytest

from episcatter import cmd_compare, metrics
from episcatter.imageio import write_exr


@pytest.fixture
def rng():
    return np.random.default_rng(7)


# Tiny hand-computable pair: four values, errors 1, 0, -1, 2.
TEST = np.array([2.0, 1.0, 0.0, 4.0]).reshape(1, 4, 1)
REF = np.array([1.0, 1.0, 1.0, 2.0]).reshape(1, 4, 1)


def test_pixelwise_metrics_by_hand():
    eps = 0.5
    assert metrics.relmse_absolute(TEST, REF, eps) == pytest.approx((1 / 1.5 + 0 + 1 / 1.5 + 4 / 4.5) / 4)
    assert metrics.rmse(TEST, REF) == pytest.approx(np.sqrt((1 + 0 + 1 + 4) / 4))
    assert metrics.mape(TEST, REF, eps) == pytest.approx((1 / 1.5 + 0 + 1 / 1.5 + 2 / 2.5) / 4)
    assert metrics.max_error(TEST, REF) == 2.0
    assert metrics.mean_ratio(TEST, REF) == pytest.approx(7 / 5)
    assert np.isnan(metrics.mean_ratio(TEST, np.zeros_like(REF)))


def test_default_eps_is_documented():
    assert metrics.DEFAULT_EPS == 1e-2
    assert metrics.relmse_absolute(np.array([1.0]), np.array([0.0])) == pytest.approx(100.0)


def _slow_block_average(img, k):
    h, w = img.shape[0] // k, img.shape[1] // k
    out = np.zeros((h, w) + img.shape[2:])
    for i in range(h):
        for j in range(w):
            out[i, j] = img[i * k:(i + 1) * k, j * k:(j + 1) * k].mean(axis=(0, 1))
    return out


@pytest.mark.parametrize("shape", [(7, 10, 3), (9, 8)])
@pytest.mark.parametrize("k", [1, 2, 3])
def test_block_average_matches_loop(rng, shape, k):
    img = rng.random(shape)
    np.testing.assert_allclose(metrics.block_average(img, k), _slow_block_average(img, k))


def test_block_average_rejects_bad_sizes():
    with pytest.raises(ValueError):
        metrics.block_average(np.zeros((4, 4, 3)), 0)
    with pytest.raises(ValueError):
        metrics.block_average(np.zeros((4, 4, 3)), 5)


def test_identical_images(rng):
    img = rng.random((16, 16, 3))
    assert metrics.relmse_absolute(img, img) == 0.0
    assert metrics.flip(img, img) == pytest.approx(0.0, abs=1e-6)
    result = metrics.compare(img, img)
    assert result["relmse"] == 0.0 and result["mean_ratio"] == 1.0


def test_flip_grows_with_difference(rng):
    ref = rng.random((16, 16, 3))
    small = metrics.flip(ref * 1.05, ref)
    large = metrics.flip(ref * 2.0, ref)
    assert 0.0 < small < large


def test_flip_dark_and_black_references(rng):
    ref = rng.random((8, 8, 3)) * 1e-9  # would make the native FLIP exit the process
    assert metrics.flip(ref * 2, ref) == pytest.approx(metrics.flip(ref * 2e9, ref * 1e9), rel=1e-4)
    with pytest.raises(ValueError, match="all-black"):
        metrics.flip(ref, np.zeros_like(ref))
    with pytest.raises(ValueError, match="rejected"):
        metrics.flip(ref, ref, parameters={"ppd": -1.0})


def test_shape_mismatch_names_both_shapes():
    with pytest.raises(ValueError, match=r"\(4, 4, 3\).*\(4, 5, 3\)"):
        metrics.compare(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))
    with pytest.raises(ValueError, match="shape mismatch"):
        metrics.relmse_absolute(np.zeros(3), np.zeros(4))


def test_compare_reports_nonfinite(rng):
    ref = rng.random((8, 8, 3)) + 0.5
    test = ref.copy()
    test[0, 0, 1] = np.nan
    test[3, 5, 0] = np.inf
    test[7, 7] = ref[7, 7] + 1.0
    result = metrics.compare(test, ref)
    assert result["nonfinite_test"] == 2 and result["nonfinite_ref"] == 0
    assert result["pixels_used"] == 62
    assert np.isfinite(result["relmse"]) and result["max_error"] == pytest.approx(1.0)
    assert np.isfinite(result["flip"])


def test_compare_block_and_keys(rng):
    ref = rng.random((9, 12, 3))
    result = metrics.compare(ref + 0.1, ref, block=3, eps=0.05)
    assert result["compared_shape"] == [3, 4, 3] and result["test_shape"] == [9, 12, 3]
    assert result["block"] == 3 and result["eps"] == 0.05
    assert result["rmse"] == pytest.approx(0.1)
    for key in ("relmse", "mape", "max_error", "mean_ratio", "flip"):
        assert np.isfinite(result[key])


def test_compare_black_reference_reports_flip_error():
    result = metrics.compare(np.ones((4, 4, 3)), np.zeros((4, 4, 3)))
    assert np.isnan(result["flip"]) and "all-black" in result["flip_error"]
    assert result["relmse"] == np.inf   # scale-free: any light on a black image
    absolute = metrics.compare(np.ones((4, 4, 3)), np.zeros((4, 4, 3)), eps_mode="absolute")
    assert absolute["relmse"] == pytest.approx(100.0)


def _scattering_like(rng, shape=(24, 32, 3)):
    """A dim image like our scattering layers (0.005-0.05) and a 'correct'
    render of it (1 % noise)."""
    ref = 0.005 + 0.045 * rng.random(shape)
    return ref, ref * (1.0 + 0.01 * rng.standard_normal(shape))


def test_compare_default_relmse_is_scale_free(rng):
    ref, good = _scattering_like(rng)
    results = [metrics.compare(good * s, ref * s) for s in (1.0, 1e-3, 1e3)]
    for r in results[1:]:
        assert r["relmse"] == pytest.approx(results[0]["relmse"], rel=1e-9)
        assert r["max_error_over_peak"] == pytest.approx(results[0]["max_error_over_peak"],
                                                          rel=1e-9)
    assert results[0]["eps_mode"] == "relative"
    assert "scale-free" in results[0]["relmse_convention"]


def test_energy_loss_scores_far_worse_than_a_correct_render(rng):
    """Issue 10, defect 1: an image at 0.44 of the right brightness scored
    like a correct one with the absolute eps (MSE x 100 for dim images)."""
    ref, good = _scattering_like(rng)
    dark = ref * 0.44
    assert metrics.compare(dark, ref)["relmse"] > 1e3 * metrics.compare(good, ref)["relmse"]
    assert metrics.compare(dark, ref)["mean_ratio"] == pytest.approx(0.44)
    # the absolute form (kept as an option) hides it: both below 1e-4
    absolute = [metrics.compare(img, ref, eps_mode="absolute")["relmse"] for img in (good, dark)]
    assert max(absolute) < 1e-1 and absolute[1] / absolute[0] < 1e4


def test_eps_and_mode_are_checked():
    img = np.ones((2, 2, 3))
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="must be a finite number > 0"):
            metrics.compare(img, img, eps=bad)
    with pytest.raises(ValueError, match="not one of"):
        metrics.compare(img, img, eps_mode="percent")


def test_noise_relmse_relative_mode_is_scale_free(rng):
    a, b = rng.random((16, 16, 3)), rng.random((16, 16, 3))
    assert metrics.noise_relmse(a * 1e-3, b * 1e-3) == pytest.approx(metrics.noise_relmse(a, b))
    v = rng.random((16, 16, 3))
    assert metrics.noise_relmse_from_variance(a * 1e-3, v * 1e-6) == \
        pytest.approx(metrics.noise_relmse_from_variance(a, v))


@pytest.mark.parametrize("block", [1, 2])
def test_noise_relmse_recovers_known_variance(rng, block):
    truth = np.full((64, 64, 3), 2.0)
    sigma = 0.2  # per-half standard deviation
    a = truth + rng.normal(0.0, sigma, truth.shape)
    b = truth + rng.normal(0.0, sigma, truth.shape)
    estimate = metrics.noise_relmse(a, b, block=block, eps_mode="absolute")
    expected = sigma**2 / 2 / block**2 / (2.0**2 + metrics.DEFAULT_EPS)
    assert estimate == pytest.approx(expected, rel=0.1)
    # ...and it predicts the actual relMSE of the combined image.
    actual = metrics.relmse_absolute(metrics.block_average((a + b) / 2, block), metrics.block_average(truth, block))
    assert estimate == pytest.approx(actual, rel=0.1)


def _parse(argv):
    parser = argparse.ArgumentParser()
    cmd_compare.add_arguments(parser)
    return parser.parse_args(argv)


def test_compare_command_json(tmp_path, rng, capsys):
    ref = rng.random((8, 8, 3)) + 0.1
    test = ref * 1.1
    test[0, 0, 0] = np.nan
    write_exr(tmp_path / "test.exr", test)
    write_exr(tmp_path / "ref.exr", {"full": ref, "depth": ref[..., 0]})

    args = _parse([str(tmp_path / "test.exr"), str(tmp_path / "ref.exr"), "--json", "--block", "2",
                   "--eps", "0.1"])
    assert cmd_compare.run(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["block"] == 2 and out["eps"] == 0.1 and out["nonfinite_test"] == 1
    assert out["compared_shape"] == [4, 4, 3]
    assert out["mean_ratio"] == pytest.approx(1.1, rel=1e-3)
    assert out["flip"] > 0


def test_compare_command_table_and_missing_file(tmp_path, rng, capsys):
    img = rng.random((4, 4, 3))
    write_exr(tmp_path / "a.exr", img)
    assert cmd_compare.run(_parse([str(tmp_path / "a.exr"), str(tmp_path / "a.exr")])) == 0
    out = capsys.readouterr().out
    assert "relMSE (scale-free relMSE, eps 0.01·mean(ref)²)" in out and "HDR-FLIP" in out

    with pytest.raises(FileNotFoundError, match="missing.exr"):
        cmd_compare.run(_parse([str(tmp_path / "a.exr"), str(tmp_path / "missing.exr")]))


def test_the_obvious_name_is_the_scale_free_relmse():
    """``metrics.relmse`` is the relMSE every table reports (scale-free);
    the exposure-dependent form has an explicit name."""
    rng = np.random.default_rng(3)
    ref = rng.uniform(0.0, 0.05, (6, 5, 3))
    test = ref * rng.uniform(0.9, 1.1, ref.shape)
    assert metrics.relmse(test, ref) == metrics.scale_free_relmse(test, ref)
    assert metrics.relmse(100 * test, 100 * ref) == pytest.approx(metrics.relmse(test, ref))
    assert metrics.relmse_absolute(100 * test, 100 * ref) != pytest.approx(
        metrics.relmse_absolute(test, ref))
