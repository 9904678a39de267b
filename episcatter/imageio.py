"""Multi-layer OpenEXR input/output and sRGB PNG previews.

EXR channel naming convention (used by :func:`write_exr`, inverted by
:func:`read_exr`):

=======================  ===============================================
layer name and shape     EXR channels
=======================  ===============================================
``full``, (H, W, 3)      ``R``, ``G``, ``B``  (the main image)
``full``, (H, W)         ``Y``
``full``, (H, W, 4)      ``R``, ``G``, ``B``, ``A``
``<name>``, (H, W, 3)    ``<name>.R``, ``<name>.G``, ``<name>.B``
``<name>``, (H, W, 4)    ``<name>.R``, ``<name>.G``, ``<name>.B``, ``<name>.A``
``<name>``, (H, W)       ``<name>.Y``  (e.g. ``distance`` -> ``distance.Y``)
=======================  ===============================================

Files are written as single-part scanline EXRs with ZIP compression and
32-bit float channels.  (H, W, 1) arrays are treated as (H, W).

Reading accepts files from other tools (any compression, half/float/uint
channels, only the first part of multi-part files).  Channels are grouped by
the prefix before their last ``.``; channels without a dot belong to the main
layer ``full``.  A group containing ``R``, ``G``, ``B`` becomes an (H, W, 3)
layer ((H, W, 4) if it also has ``A``); a group holding only ``Y`` becomes an
(H, W) layer; any other channel becomes an (H, W) layer named by its full
channel name (e.g. ``Z`` or ``depth.Z``).  All arrays are returned as float32.

Mitsuba's ``mi.util.write_bitmap`` is deliberately not used for EXR output
(it deadlocks in this environment); this module does not import Mitsuba.
"""

from __future__ import annotations

import errno
import os
import warnings
from collections.abc import Mapping

import numpy as np
import OpenEXR

MAIN_LAYER = "full"
"""Name of the main RGB layer, stored in the un-prefixed ``R``, ``G``, ``B`` channels."""

_COLOR_SUFFIXES = ("R", "G", "B", "A")
_SCALAR_SUFFIX = "Y"

# Header attributes that OpenEXR manages itself; metadata may not override them.
_RESERVED_HEADER_KEYS = frozenset({
    "channels", "chunkCount", "compression", "dataWindow", "displayWindow",
    "lineOrder", "name", "pixelAspectRatio", "screenWindowCenter",
    "screenWindowWidth", "tiles", "type", "version",
})


# --------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------

def _normalize_layers(layers) -> dict[str, np.ndarray]:
    """Validate ``layers`` and return a dict name -> float32 (H, W) or (H, W, 3|4) array."""
    if isinstance(layers, np.ndarray):
        layers = {MAIN_LAYER: layers}
    if not isinstance(layers, Mapping):
        raise TypeError("layers must be a dict name -> array or a single (H, W, 3) array, "
                        f"got {type(layers).__name__}")
    if not layers:
        raise ValueError("layers is empty: nothing to write")
    out: dict[str, np.ndarray] = {}
    for name, arr in layers.items():
        if not isinstance(name, str) or not name or name.startswith(".") or name.endswith("."):
            raise ValueError(f"invalid layer name {name!r}: must be a non-empty string "
                             "that does not start or end with '.'")
        a = np.asarray(arr, dtype=np.float32)
        if a.ndim == 3 and a.shape[2] == 1:
            a = a[..., 0]
        if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (3, 4)):
            raise ValueError(f"layer {name!r} has shape {a.shape}; expected (H, W), (H, W, 1), "
                             "(H, W, 3) or (H, W, 4)")
        out[name] = a
    sizes = {a.shape[:2] for a in out.values()}
    if len(sizes) != 1:
        detail = ", ".join(f"{n}: {a.shape}" for n, a in out.items())
        raise ValueError(f"all layers must have the same height and width ({detail})")
    return out


def _channel_names(layer: str, num_channels: int) -> list[str]:
    """EXR channel names of a layer with ``num_channels`` channels (1, 3 or 4)."""
    prefix = "" if layer == MAIN_LAYER else layer + "."
    suffixes = (_SCALAR_SUFFIX,) if num_channels == 1 else _COLOR_SUFFIXES[:num_channels]
    return [prefix + s for s in suffixes]


def _metadata_attributes(metadata) -> dict[str, str]:
    """Check user metadata and convert it to string header attributes."""
    if metadata is None:
        return {}
    attrs: dict[str, str] = {}
    for key, value in dict(metadata).items():
        if not isinstance(key, str) or not key:
            raise ValueError(f"metadata keys must be non-empty strings, got {key!r}")
        if key in _RESERVED_HEADER_KEYS:
            raise ValueError(f"metadata key {key!r} is a reserved EXR header attribute")
        if isinstance(value, (bool, int, float, np.number)):
            value = str(value)
        if not isinstance(value, str):
            raise TypeError(f"metadata value for {key!r} must be a string (or number), "
                            f"got {type(value).__name__}")
        attrs[key] = value
    return attrs


def write_exr(path, layers, metadata: Mapping[str, str] | None = None) -> None:
    """Write one multi-layer EXR file (ZIP compression, float32 channels).

    Parameters
    ----------
    path:
        Output file path (str or path-like).  Its directory must exist.
    layers:
        Either a dict ``name -> array`` with arrays of shape (H, W), (H, W, 1),
        (H, W, 3) or (H, W, 4), all with the same H and W, or a single
        (H, W, 3) array, which is written as the main layer ``full``.
        See the module docstring for the channel naming convention.
    metadata:
        Optional dict of string header attributes (numbers are converted with
        ``str``).  Standard EXR attribute names (``compression``, ...) are refused.
    """
    layers = _normalize_layers(layers)
    channels: dict[str, np.ndarray] = {}
    for name, arr in layers.items():
        planes = [arr] if arr.ndim == 2 else [arr[..., c] for c in range(arr.shape[2])]
        for cname, plane in zip(_channel_names(name, len(planes)), planes):
            channels[cname] = np.ascontiguousarray(plane, dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update(_metadata_attributes(metadata))
    with OpenEXR.File(header, channels) as exr:
        exr.write(os.fspath(path))


# --------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------

def _open_exr(path, header_only: bool = False):
    """Open an EXR file, raising FileNotFoundError / ValueError that name the path."""
    p = os.fspath(path)
    if not os.path.isfile(p):
        raise FileNotFoundError(errno.ENOENT, "EXR file not found", p)
    try:
        return OpenEXR.File(p, separate_channels=True, header_only=header_only)
    except RuntimeError as exc:
        raise ValueError(f"cannot read EXR file {p!r}: {exc}") from exc


def _group_channels(channels: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Group EXR channels into layers following the module's naming convention."""
    groups: dict[str, dict[str, np.ndarray]] = {}
    for cname, arr in channels.items():
        prefix, _, suffix = cname.rpartition(".")
        groups.setdefault(prefix, {})[suffix] = arr

    layers: dict[str, np.ndarray] = {}
    leftovers: dict[str, np.ndarray] = {}
    for prefix, chans in groups.items():
        name = prefix or MAIN_LAYER
        rest = dict(chans)
        if {"R", "G", "B"} <= rest.keys():
            keys = ["R", "G", "B"] + (["A"] if "A" in rest else [])
            layers[name] = np.stack([rest.pop(k) for k in keys], axis=-1)
        elif rest.keys() == {_SCALAR_SUFFIX}:
            layers[name] = rest.pop(_SCALAR_SUFFIX)
        for suffix, arr in rest.items():
            leftovers[f"{prefix}.{suffix}" if prefix else suffix] = arr

    for cname, arr in leftovers.items():
        if cname in layers:
            warnings.warn(f"EXR channel {cname!r} clashes with a layer of the same name; "
                          "it is not returned", stacklevel=3)
            continue
        layers[cname] = arr

    ordered = {MAIN_LAYER: layers.pop(MAIN_LAYER)} if MAIN_LAYER in layers else {}
    ordered.update(layers)
    return ordered


def read_exr(path) -> dict[str, np.ndarray]:
    """Read an EXR file into a dict ``layer name -> float32 array``.

    Inverse of :func:`write_exr` (names, shapes and float32 values round-trip
    exactly).  Also reads EXRs written by other tools; see the module
    docstring for how channels are grouped into layers.  Only the first part
    of a multi-part file is read.

    Raises FileNotFoundError if ``path`` does not exist and ValueError if it
    is not a readable EXR file.
    """
    with _open_exr(path) as exr:
        # Copy the pixels inside the context; closing the file releases its data.
        channels = {name: np.array(ch.pixels, dtype=np.float32, copy=True)
                    for name, ch in exr.channels().items()}
    return _group_channels(channels)


def read_rgb(path) -> np.ndarray:
    """Read the main RGB image of an EXR file as a (H, W, 3) float32 array.

    The main layer is ``full`` (channels ``R``, ``G``, ``B``; alpha is
    dropped; a luminance-only ``Y`` image is replicated to three channels).
    If there is no main layer but exactly one layer, that layer is used.
    """
    layers = read_exr(path)
    if MAIN_LAYER in layers:
        img = layers[MAIN_LAYER]
    elif len(layers) == 1:
        img = next(iter(layers.values()))
    else:
        raise ValueError(f"{os.fspath(path)!r} has no main R,G,B layer; layers: {sorted(layers)}")
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    return np.ascontiguousarray(img[..., :3], dtype=np.float32)


def read_metadata(path) -> dict[str, str]:
    """Return the string-valued header attributes of an EXR file (e.g. metadata
    given to :func:`write_exr`), without reading pixel data."""
    with _open_exr(path, header_only=True) as exr:
        # Copy inside the context: closing the file empties its header dict.
        return {k: v for k, v in exr.header().items() if isinstance(v, str)}


# --------------------------------------------------------------------------
# PNG previews
# --------------------------------------------------------------------------

def auto_exposure_scale(rgb: np.ndarray, percentile: float = 99.0, target: float = 0.9) -> float:
    """Linear scale that maps the ``percentile``-th percentile of the per-pixel
    maximum channel of ``rgb`` to ``target``.

    Non-finite values are ignored.  Falls back to the maximum if the
    percentile is zero, and to 1.0 for an all-black image.
    """
    peak = np.max(np.asarray(rgb, dtype=np.float64), axis=-1) if np.ndim(rgb) == 3 else np.asarray(rgb)
    peak = peak[np.isfinite(peak)]
    if peak.size == 0:
        return 1.0
    level = float(np.percentile(peak, percentile))
    if level <= 0.0:
        level = float(peak.max())
    return target / level if level > 0.0 else 1.0


def _encode_srgb(linear: np.ndarray) -> np.ndarray:
    """sRGB-encode linear values in [0, 1] with colour-science."""
    with warnings.catch_warnings():
        # colour warns on import when SciPy is missing; irrelevant here.
        warnings.simplefilter("ignore")
        import colour
    return np.asarray(colour.cctf_encoding(linear, function="sRGB"), dtype=np.float64)


def write_png_preview(path, rgb: np.ndarray, exposure: float | str = 0.0) -> float:
    """Write a linear HDR image as an 8-bit sRGB PNG preview.

    The image is multiplied by ``2**exposure`` (exposure in stops; the
    default 0.0 means no scaling) or, if ``exposure == 'auto'``, by
    :func:`auto_exposure_scale` (99th percentile of the per-pixel max channel
    -> 0.9).  It is then clipped to [0, 1], encoded with the sRGB transfer
    function (``colour.cctf_encoding``) and quantized to 8 bits.  NaN and
    -inf become black, +inf white.  ``rgb`` may be (H, W), (H, W, 3) or
    (H, W, 4) (alpha is ignored).  Returns the linear scale factor applied.
    """
    from PIL import Image

    img = np.asarray(rgb, dtype=np.float64)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=-1)
    if img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ValueError(f"expected an (H, W), (H, W, 3) or (H, W, 4) image, got shape {img.shape}")
    img = img[..., :3]
    if isinstance(exposure, str):
        if exposure != "auto":
            raise ValueError(f"exposure must be a number of stops or 'auto', got {exposure!r}")
        scale = auto_exposure_scale(img)
    else:
        scale = 2.0 ** float(exposure)
    img = np.nan_to_num(img * scale, nan=0.0, posinf=1.0, neginf=0.0)
    encoded = _encode_srgb(np.clip(img, 0.0, 1.0))
    pixels = np.round(np.clip(encoded, 0.0, 1.0) * 255.0).astype(np.uint8)
    Image.fromarray(pixels).save(os.fspath(path), format="PNG")
    return scale


def output_paths(path) -> tuple[str, str]:
    """(EXR, PNG preview) written for an output name: ``x.exr`` -> ``x.exr``
    + ``x.png``; ``x.png`` -> the same pair (the preview never overwrites the
    EXR).  Checked before anything is rendered: another suffix, or a folder
    that does not exist, is a ``ValueError`` / ``FileNotFoundError`` naming
    the fix."""
    path = os.fspath(path)
    stem, ext = os.path.splitext(path)
    if ext.lower() not in (".exr", ".png"):
        raise ValueError(f"output '{path}' must end in .exr or .png (both the EXR and an "
                         "sRGB PNG preview are written).")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"output folder '{folder}' does not exist: create it first "
                                f"(mkdir -p {folder}) or write elsewhere.")
    return stem + ".exr", stem + ".png"
