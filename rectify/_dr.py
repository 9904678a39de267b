"""Small Dr.Jit helpers shared by the ``rectify`` modules.

Frame constants enter kernels as *opaque* scalars (``dr.opaque``): a new
camera or light then reuses the compiled kernels instead of baking new
literals into new ones.  Everything uses the active Mitsuba variant's types
(``mi.Float``, ``mi.Vector3f``...), never a specific backend.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np


#: NumPy dtype of each Dr.Jit scalar type an opaque scalar may have
_DTYPES = {dr.VarType.Float32: np.float32, dr.VarType.Float64: np.float64,
           dr.VarType.UInt32: np.uint32, dr.VarType.Int32: np.int32,
           dr.VarType.UInt64: np.uint64, dr.VarType.Int64: np.int64, dr.VarType.Bool: np.bool_}


def _opaque(tp, value):
    """One evaluated entry of type ``tp`` holding ``value``, made from host
    memory: what ``dr.opaque`` makes, without the kernel that writes it
    (a copy from a NumPy buffer, on the CPU none at all).  An integer type
    takes whole numbers only (a fraction is a caller's bug, not a value
    to truncate)."""
    kind = dr.type_v(tp)
    if kind not in _DTYPES:
        raise TypeError(f"an opaque scalar of {tp.__name__} is not supported; use one of "
                        f"{sorted(str(k) for k in _DTYPES)}.")
    dtype = _DTYPES[kind]
    if np.issubdtype(dtype, np.integer) and not (math.isfinite(value) and int(value) == value):
        raise ValueError(f"opaque {tp.__name__} scalar {value!r} is not a whole number.")
    with np.errstate(over="ignore"):
        host = np.asarray([value], dtype=dtype)
    return tp(aligned(host, host.dtype))


def opaque_scalar(tp, value):
    """An opaque ``tp`` scalar holding ``value``: a kernel parameter of its
    own, not a literal.  Never one variable with an equal value elsewhere:
    two values equal in one frame and not in the next would change the
    kernel's parameters, a new kernel (a light's coordinate and σt, two
    zeros of a rotation, two sizes)."""
    return _opaque(tp, value)


def const(value) -> mi.Float:
    """An opaque ``mi.Float`` scalar."""
    return opaque_scalar(mi.Float, float(value))


def const_u32(value) -> mi.UInt32:
    """An opaque ``mi.UInt32`` scalar."""
    return opaque_scalar(mi.UInt32, int(value))


def vec3(v) -> mi.Vector3f:
    """An opaque ``mi.Vector3f`` holding the NumPy 3-vector ``v``."""
    v = np.asarray(v, dtype=np.float64)
    return mi.Vector3f(const(v[0]), const(v[1]), const(v[2]))


#: alignment of the NumPy buffers handed to Dr.Jit (the widest CPU vector)
ALIGNMENT = 64


def aligned(values, dtype) -> np.ndarray:
    """A contiguous 1-D copy of ``values`` as ``dtype`` at an
    ``ALIGNMENT``-byte aligned address: on a CPU backend Dr.Jit may read a
    NumPy array in place, and a kernel that loads it lane by lane records
    whether its address is aligned, so a new allocation at another
    alignment would compile a new kernel."""
    values = np.asarray(values, dtype=dtype).reshape(-1)
    itemsize = np.dtype(dtype).itemsize
    buf = np.empty(values.size + ALIGNMENT // itemsize, dtype=dtype)
    start = (-buf.ctypes.data % ALIGNMENT) // itemsize
    out = buf[start:start + values.size]
    out[...] = values
    return out


def floats(values) -> mi.Float:
    """A NumPy array (flattened) as an ``mi.Float`` (float32 on every
    variant), from aligned memory (:func:`aligned`)."""
    return mi.Float(aligned(values, np.float32))


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


def host_array(value) -> np.ndarray:
    """A Dr.Jit value (scalar, array, vector, colour, matrix) as a float64
    NumPy array, read component by component: ``np.array`` of a nested
    array (an ``Array3f``, a ``Matrix4f``) packs it in a kernel of its own,
    while an evaluated component is a plain copy.  Flat order: component
    by component (``[x..., y..., z...]``; a matrix row by row), as
    ``np.array(value).reshape(-1)`` of a width-1 value."""
    if dr.is_array_v(value) and dr.depth_v(value) > 1:
        return np.concatenate([host_array(value[i]) for i in range(len(value))])
    return np.asarray(value, dtype=np.float64).reshape(-1)


def drain_jit_kernels() -> list:
    """The JIT kernels in Dr.Jit's kernel history since it was last read
    (reading empties it; the other entries -- reductions, prefix sums,
    memory copies -- are dropped)."""
    return [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
