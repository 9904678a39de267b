"""Small Dr.Jit helpers shared by the ``rectify`` modules.

Frame constants enter kernels as *opaque* scalars (``dr.opaque``): a new
camera or light then reuses the compiled kernels instead of baking new
literals into new ones.  Everything uses the active Mitsuba variant's types
(``mi.Float``, ``mi.Vector3f``...), never a specific backend.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np


def const(value) -> mi.Float:
    """An opaque ``mi.Float`` scalar."""
    return dr.opaque(mi.Float, float(value))


def const_u32(value) -> mi.UInt32:
    return dr.opaque(mi.UInt32, int(value))


def vec3(v) -> mi.Vector3f:
    """An opaque ``mi.Vector3f`` holding the NumPy 3-vector ``v``."""
    v = np.asarray(v, dtype=np.float64)
    return mi.Vector3f(const(v[0]), const(v[1]), const(v[2]))


def floats(values) -> mi.Float:
    """A NumPy 1-D array as an ``mi.Float`` (float32 on every variant)."""
    return mi.Float(np.ascontiguousarray(np.asarray(values, dtype=np.float32).ravel()))


def pixel_centres(width: int, height: int):
    """(x, y) of every pixel centre, flat row-major (index = y*width + x)."""
    idx = dr.arange(mi.UInt32, int(width) * int(height))
    w = const_u32(width)
    y = idx // w
    x = idx - y * w
    return mi.Float(x) + 0.5, mi.Float(y) + 0.5


def to_numpy(a) -> np.ndarray:
    """A Dr.Jit array (or NumPy array) as a NumPy array."""
    return np.asarray(a)


def to_image(a, width: int, height: int) -> np.ndarray:
    """A flat per-pixel Dr.Jit array as a NumPy (height, width) image."""
    return np.asarray(a).reshape(int(height), int(width))
