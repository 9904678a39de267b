"""Unrectification: (slice, beta) grid values -> image (Baran §3 "resample
the results back into the original image domain"; Yusov 2013 "Transformation
from epipolar to rectangular coordinates").

Each pixel centre lies between slices ``k0`` and ``k1`` at the fraction ``f``
in alpha (:func:`rectify.slices.pixel_to_slice`); on each of the two slices it
reads the grid linearly at its own beta (clamped to the grid's ends), and the
two are blended with ``1-f`` and ``f``: bilinear in (alpha, beta).

The depth-aware variant multiplies each of the four bilinear weights by
``exp(-((d_i - d) / (sigma * d))^2 / 2)`` (``d_i`` the sample's depth, ``d``
the pixel's, ``sigma`` relative) and renormalises, like Yusov's bilateral
unwarp.  It also returns the weight sum: where it is tiny no sample shares
the pixel's depth (the value falls back to plain bilinear) and the caller
should fix the pixel up (Yusov: "Fix-up pass").

Grid values: ``(S, M)`` or ``(S, M, C)`` (``mi.TensorXf`` or NumPy); images
come back as ``mi.TensorXf`` of shape ``(H, W)`` or ``(H, W, C)``; the
``*_reference`` twins take and return NumPy arrays.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ._dr import const, const_u32, floats
from .coords import pixel_to_alpha_beta
from .epipole import EpipolarFrame
from .grid import BetaGrid
from .slices import Slices, alpha_to_slice, pixel_to_slice_reference

#: weight sums below this count as "no usable sample" in the bilateral unwarp
MIN_WEIGHT = 1e-6


def _as_tensor(values) -> mi.TensorXf:
    if isinstance(values, mi.TensorXf):
        return values
    return mi.TensorXf(np.ascontiguousarray(np.asarray(values, dtype=np.float32)))


def _check(values_shape, slices: Slices, grid: BetaGrid):
    if len(values_shape) not in (2, 3) or tuple(values_shape[:2]) != (slices.count, grid.count):
        raise ValueError(f"grid values must have shape (S, M[, C]) = ({slices.count}, "
                         f"{grid.count}[, C]), got {tuple(values_shape)}")


def _lanes(frame: EpipolarFrame, channels: int):
    """Per (pixel, channel) lane: pixel centre x, y and channel index."""
    W, H = frame.width, frame.height
    i = dr.arange(mi.UInt32, W * H * channels)
    pix = i // const_u32(channels)
    c = i - pix * const_u32(channels)
    y = pix // const_u32(W)
    x = pix - y * const_u32(W)
    return mi.Float(x) + 0.5, mi.Float(y) + 0.5, c, pix


def _taps(frame, slices, grid, x, y):
    """The four (flat sample index, bilinear weight) taps of each lane."""
    M = grid.count
    alpha, beta = pixel_to_alpha_beta(frame, x, y)
    k0, k1, f = alpha_to_slice(slices, alpha)
    start, step = floats(grid.start), floats(grid.step)
    taps = []
    for k, wk in ((k0, 1.0 - f), (k1, f)):
        jf = (beta - dr.gather(mi.Float, start, k)) / dr.gather(mi.Float, step, k)
        jf = dr.clip(jf, 0.0, const(M - 1))
        j0 = dr.minimum(mi.UInt32(dr.floor(jf)), const_u32(M - 2))
        fj = jf - mi.Float(j0)
        base = k * const_u32(M) + j0
        taps += [(base, wk * (1.0 - fj)), (base + 1, wk * fj)]
    return taps


def _image(arr: mi.Float, frame: EpipolarFrame, channels: int, squeeze: bool) -> mi.TensorXf:
    shape = (frame.height, frame.width) if squeeze else (frame.height, frame.width, channels)
    return mi.TensorXf(arr, shape=shape)


def unrectify(frame: EpipolarFrame, slices: Slices, grid: BetaGrid, values) -> mi.TensorXf:
    """Bilinear (alpha, beta) resampling of grid values to every pixel centre."""
    values = _as_tensor(values)
    _check(values.shape, slices, grid)
    C = values.shape[2] if len(values.shape) == 3 else 1
    x, y, c, _ = _lanes(frame, C)
    out = dr.zeros(mi.Float, dr.width(x))
    for idx, w in _taps(frame, slices, grid, x, y):
        out += w * dr.gather(mi.Float, values.array, idx * const_u32(C) + c)
    return _image(out, frame, C, len(values.shape) == 2)


def unrectify_bilateral(frame: EpipolarFrame, slices: Slices, grid: BetaGrid, values,
                        sample_depth, pixel_depth, depth_sigma: float = 0.1):
    """Depth-aware unrectification; ``sample_depth`` (S, M) and ``pixel_depth``
    (H, W) in the same units (e.g. distance along the view ray).  Returns
    ``(image, weight_sum)``; weight_sum (H, W) < MIN_WEIGHT marks pixels to fix up."""
    values = _as_tensor(values)
    _check(values.shape, slices, grid)
    sd = _as_tensor(sample_depth)
    pd = _as_tensor(pixel_depth)
    if tuple(sd.shape) != (slices.count, grid.count) or tuple(pd.shape) != (frame.height, frame.width):
        raise ValueError("sample_depth must be (S, M) and pixel_depth (H, W)")
    C = values.shape[2] if len(values.shape) == 3 else 1
    x, y, c, pix = _lanes(frame, C)
    d = dr.gather(mi.Float, pd.array, pix)
    inv = 1.0 / (const(depth_sigma) * dr.maximum(dr.abs(d), 1e-20))
    num = dr.zeros(mi.Float, dr.width(x))
    den = dr.zeros(mi.Float, dr.width(x))
    plain = dr.zeros(mi.Float, dr.width(x))
    for idx, w in _taps(frame, slices, grid, x, y):
        v = dr.gather(mi.Float, values.array, idx * const_u32(C) + c)
        z = (dr.gather(mi.Float, sd.array, idx) - d) * inv
        wb = w * dr.exp(-0.5 * z * z)
        num += wb * v
        den += wb
        plain += w * v
    ok = den >= MIN_WEIGHT
    out = dr.select(ok, num / dr.select(ok, den, 1.0), plain)
    wsum = dr.gather(mi.Float, den, dr.arange(mi.UInt32, frame.width * frame.height) * const_u32(C))
    return (_image(out, frame, C, len(values.shape) == 2),
            mi.TensorXf(wsum, shape=(frame.height, frame.width)))


# --------------------------------------------------------------------------
# NumPy references: one pixel at a time
# --------------------------------------------------------------------------


def _reference_taps(frame, slices, grid):
    """For each pixel (row-major): list of 4 (k, j, weight)."""
    _, beta, k0, k1, f = pixel_to_slice_reference(frame, slices)
    M = grid.count
    out = []
    for b, ka, kb, fa in zip(beta, k0, k1, f):
        taps = []
        for k, wk in ((ka, 1.0 - fa), (kb, fa)):
            jf = min(max((b - grid.start[k]) / grid.step[k], 0.0), M - 1.0)
            j0 = min(int(np.floor(jf)), M - 2)
            fj = jf - j0
            taps += [(k, j0, wk * (1.0 - fj)), (k, j0 + 1, wk * fj)]
        out.append(taps)
    return out


def unrectify_reference(frame: EpipolarFrame, slices: Slices, grid: BetaGrid, values) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64)
    _check(v.shape, slices, grid)
    out = np.zeros((frame.height * frame.width,) + v.shape[2:])
    for p, taps in enumerate(_reference_taps(frame, slices, grid)):
        out[p] = sum(w * v[k, j] for k, j, w in taps)
    return out.reshape((frame.height, frame.width) + v.shape[2:])


def unrectify_bilateral_reference(frame, slices, grid, values, sample_depth, pixel_depth,
                                  depth_sigma: float = 0.1):
    v = np.asarray(values, dtype=np.float64)
    _check(v.shape, slices, grid)
    sd = np.asarray(sample_depth, dtype=np.float64)
    pd = np.asarray(pixel_depth, dtype=np.float64).ravel()
    out = np.zeros((frame.height * frame.width,) + v.shape[2:])
    wsum = np.zeros(frame.height * frame.width)
    for p, taps in enumerate(_reference_taps(frame, slices, grid)):
        d = pd[p]
        ws = [w * np.exp(-0.5 * ((sd[k, j] - d) / (depth_sigma * max(abs(d), 1e-20))) ** 2)
              for k, j, w in taps]
        wsum[p] = sum(ws)
        if wsum[p] >= MIN_WEIGHT:
            out[p] = sum(wb * v[k, j] for (k, j, _), wb in zip(taps, ws)) / wsum[p]
        else:
            out[p] = sum(w * v[k, j] for k, j, w in taps)
    shape = (frame.height, frame.width)
    return out.reshape(shape + v.shape[2:]), wsum.reshape(shape)
