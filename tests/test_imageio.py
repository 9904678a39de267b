"""Tests of episcatter.imageio: EXR round trips, foreign EXRs, PNG previews."""

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from episcatter.imageio import (read_exr, read_metadata, read_rgb, write_exr,
                                write_png_preview)

H, W = 6, 5


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def _channel_names(path):
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        return set(exr.channels()), dict(exr.header())


def test_multilayer_round_trip(tmp_path, rng):
    layers = {
        "full": rng.random((H, W, 3), dtype=np.float32) * 10,
        "albedo": rng.random((H, W, 3), dtype=np.float32),
        "distance": rng.random((H, W), dtype=np.float32) * 100,
        "mask": rng.random((H, W, 1), dtype=np.float32),
    }
    path = tmp_path / "multi.exr"
    write_exr(path, layers, metadata={"integrator": "epipolar", "spp": 64})

    names, header = _channel_names(path)
    assert names == {"R", "G", "B", "albedo.R", "albedo.G", "albedo.B", "distance.Y", "mask.Y"}
    assert header["compression"] == OpenEXR.ZIP_COMPRESSION

    back = read_exr(path)
    assert list(back)[0] == "full"
    assert set(back) == set(layers)
    for name, arr in layers.items():
        expected = arr[..., 0] if arr.shape[-1] == 1 else arr
        assert back[name].dtype == np.float32
        assert back[name].shape == expected.shape
        np.testing.assert_array_equal(back[name], expected)

    assert read_metadata(path)["integrator"] == "epipolar"
    assert read_metadata(path)["spp"] == "64"
    np.testing.assert_array_equal(read_rgb(path), layers["full"])


def test_single_array_is_main_layer(tmp_path, rng):
    img = rng.random((H, W, 3)).astype(np.float64)  # float64 input is stored as float32
    path = tmp_path / "single.exr"
    write_exr(path, img)
    assert _channel_names(path)[0] == {"R", "G", "B"}
    np.testing.assert_array_equal(read_rgb(path), img.astype(np.float32))


@pytest.mark.parametrize("dtype", [np.float16, np.float32])
def test_read_foreign_piz_rgb(tmp_path, rng, dtype):
    img = (rng.random((H, W, 3)) * 4).astype(dtype)
    path = tmp_path / "foreign.exr"
    channels = {"R": img[..., 0].copy(), "G": img[..., 1].copy(), "B": img[..., 2].copy()}
    header = {"compression": OpenEXR.PIZ_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, channels) as exr:
        exr.write(str(path))

    rgb = read_rgb(path)
    assert rgb.dtype == np.float32 and rgb.shape == (H, W, 3)
    np.testing.assert_array_equal(rgb, img.astype(np.float32))
    assert set(read_exr(path)) == {"full"}


def test_read_foreign_rgba_and_extra_channels(tmp_path, rng):
    rgba = rng.random((H, W, 4)).astype(np.float16)
    z = rng.random((H, W)).astype(np.float32)
    channels = {"R": rgba[..., 0].copy(), "G": rgba[..., 1].copy(), "B": rgba[..., 2].copy(),
                "A": rgba[..., 3].copy(), "Z": z}
    path = tmp_path / "rgbaz.exr"
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, channels) as exr:
        exr.write(str(path))
    layers = read_exr(path)
    assert layers["full"].shape == (H, W, 4)
    np.testing.assert_array_equal(layers["Z"], z)
    np.testing.assert_array_equal(read_rgb(path), rgba[..., :3].astype(np.float32))


def test_luminance_only_image(tmp_path, rng):
    y = rng.random((H, W), dtype=np.float32)
    path = tmp_path / "y.exr"
    write_exr(path, {"full": y})
    assert _channel_names(path)[0] == {"Y"}
    rgb = read_rgb(path)
    assert rgb.shape == (H, W, 3)
    np.testing.assert_array_equal(rgb[..., 1], y)


def test_write_errors(tmp_path):
    with pytest.raises(ValueError, match="same height and width"):
        write_exr(tmp_path / "x.exr", {"full": np.zeros((2, 2, 3)), "d": np.zeros((3, 2))})
    with pytest.raises(ValueError, match="shape"):
        write_exr(tmp_path / "x.exr", {"full": np.zeros((2, 2, 2))})
    with pytest.raises(ValueError, match="reserved"):
        write_exr(tmp_path / "x.exr", np.zeros((2, 2, 3)), metadata={"compression": "none"})


def test_read_missing_file_names_path(tmp_path):
    missing = tmp_path / "nope.exr"
    with pytest.raises(FileNotFoundError, match="nope.exr"):
        read_exr(missing)


def test_png_preview(tmp_path, rng):
    img = rng.random((H, W, 3)) * 3
    path = tmp_path / "preview.png"
    assert write_png_preview(path, img) == 1.0  # default: exposure 0 stops
    with Image.open(path) as png:
        assert png.size == (W, H) and png.mode == "RGB"

    auto = tmp_path / "auto.png"
    scale = write_png_preview(auto, img, exposure="auto")
    peak = np.percentile(img.max(axis=-1), 99)
    assert scale == pytest.approx(0.9 / peak)
    with Image.open(auto) as png:
        assert png.size == (W, H)


def test_png_preview_encoding(tmp_path):
    # Linear 0.18 -> sRGB 0.4614 -> 118; values above 1 clip to 255; NaN -> 0.
    img = np.array([[[0.18, 2.0, np.nan]]])
    path = tmp_path / "px.png"
    write_png_preview(path, img)
    with Image.open(path) as png:
        assert np.asarray(png)[0, 0].tolist() == [118, 255, 0]
    write_png_preview(path, img, exposure=-1.0)  # halves the image: 2.0 -> 1.0
    with Image.open(path) as png:
        assert np.asarray(png)[0, 0, 1] == 255
