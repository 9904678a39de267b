"""Kernel inputs that do not change a kernel from one frame to the next.

* A value of the frame (camera, light, medium, slice count, a size read
  back from the device) that enters a kernel as a Python number becomes a
  literal of that kernel, and a new value compiles a new kernel.
  :func:`scalar` and its siblings make it an opaque scalar instead: a
  kernel parameter.
* A NumPy array converted with ``mi.Float(array)`` may be used in place on
  a CPU backend, and a kernel reading it lane by lane records whether its
  address is aligned to the vector width: a new allocation at another
  alignment compiles a new kernel.  :func:`floats` and :func:`uints` copy
  the array to 64-byte aligned memory first.
* ``dr.mean`` multiplies by the reciprocal lane count as a literal
  (:func:`mean` does not).
* A one-entry array is read as a scalar: a kernel over the lanes of a
  compressed index list that happens to hold one entry is another kernel
  than the one over many (:func:`two_or_more`).

Everything uses the active variant's types (``mi.Float``, ``mi.UInt32``...),
never a specific backend.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify._dr import aligned, const, const_u32, opaque_scalar  # noqa: F401


#: an opaque ``mi.Float`` / ``mi.UInt32`` holding a Python or NumPy number
#: (rectify's: each its own kernel parameter, :func:`~rectify._dr.opaque_scalar`)
scalar = const
scalar_u32 = const_u32


def scalar_i32(value) -> mi.Int32:
    """An opaque ``mi.Int32`` holding the integer ``value``."""
    return opaque_scalar(mi.Int32, int(value))


def _components(v) -> list:
    return [scalar(c) for c in np.asarray(v, dtype=np.float64).reshape(-1)[:3]]


class Divisor:
    """Division of non-negative 32-bit lanes by a frame's count ``d`` (≥ 1),
    the divisor a kernel parameter: a vector division by a value the
    compiler does not know is done lane by lane (a literal divisor is a
    multiply and shifts), so the multiplier and shifts of Granlund and
    Montgomery's method ("Division by invariant integers using
    multiplication", 1994) are computed here and passed opaque:
    ``q = (t + ((n − t) >> s1)) >> s2``, ``t = mulhi(m, n)``, exact for
    every 32-bit ``n``."""

    def __init__(self, d: int):
        d = int(d)
        if not 1 <= d < (1 << 32):
            raise ValueError(f"divisor {d} out of the 32-bit range")
        l = (d - 1).bit_length()              # ⌈log2 d⌉
        self.value = d
        self.d = scalar_u32(d)
        self.m = scalar_u32(((1 << 32) * ((1 << l) - d)) // d + 1)
        self.s1 = scalar_u32(min(l, 1))
        self.s2 = scalar_u32(max(l - 1, 0))

    def div(self, n):
        """⌊n / d⌋ (UInt32 lanes; Int32 lanes must be ≥ 0 and come back Int32)."""
        if dr.type_v(n) != dr.VarType.UInt32:
            return type(n)(self.div(mi.UInt32(n)))
        t = dr.mul_hi(self.m, n)
        return (t + ((n - t) >> self.s1)) >> self.s2

    def divmod(self, n):
        """(⌊n / d⌋, n mod d)."""
        q = self.div(n)
        return q, n - q * type(n)(self.d)


def vector(v) -> mi.Vector3f:
    """An opaque ``mi.Vector3f`` holding the NumPy 3-vector ``v``."""
    return mi.Vector3f(*_components(v))


def point(v) -> mi.Point3f:
    """An opaque ``mi.Point3f`` holding the NumPy 3-vector ``v``."""
    return mi.Point3f(*_components(v))


def colour(v) -> mi.Color3f:
    """An opaque ``mi.Color3f`` holding the RGB triple ``v``."""
    return mi.Color3f(*_components(v))


def reciprocal(value) -> mi.Float:
    """An opaque ``1/value`` rounded as Dr.Jit rounds a division by the
    literal ``value`` (the float32 reciprocal of the float32 value): ``x *
    reciprocal(c)`` is bit for bit the ``x / c`` of a kernel that had ``c``
    as a literal."""
    return scalar(np.float32(1.0) / np.float32(value))


def floats(values) -> mi.Float:
    """A NumPy array (any shape, flattened) as an ``mi.Float`` (float32)."""
    return mi.Float(aligned(values, np.float32))


def uints(values) -> mi.UInt32:
    """A NumPy array of non-negative integers (flattened) as an ``mi.UInt32``."""
    return mi.UInt32(aligned(values, np.uint32))


def two_or_more(index: mi.UInt32) -> mi.UInt32:
    """``index`` (a list of lanes to compute), or its single entry twice:
    Dr.Jit reads a one-entry array as a scalar, so a kernel over a single
    lane would be another kernel (compiled anew) than the one over many.
    The caller computes the repeated lane twice and writes the same value
    twice."""
    if dr.width(index) != 1:
        return index
    return uints([index[0], index[0]])


def mean(values: mi.Float) -> mi.Float:
    """``dr.mean(values)`` (the sum times the reciprocal lane count, the same
    float32 result) with the lane count an opaque scalar."""
    return dr.sum(values) * scalar(1.0 / dr.width(values))
