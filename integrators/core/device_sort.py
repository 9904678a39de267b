"""Sorting on the device in few kernels.

:func:`argsort_keys` is a stable least-significant-digit radix sort of
32-bit keys in two passes of 16-bit digits, each a counting sort by
``dr.detail.block_mkperm`` (Dr.Jit's stable bucket permutation).  It is the
permutation ``dr.argsort`` returns -- both are stable, so equal keys keep
their order -- in two JIT kernels instead of five (``dr.argsort`` of a
32-bit array makes three passes of 11-bit digits on the CPU, four of 8 on
the GPU, with the key's evaluation a kernel of its own); the first digit is
evaluated in one kernel with whatever the caller scheduled.
"""
from __future__ import annotations

import drjit as dr


#: bits of one radix digit (two passes cover a 32-bit key)
DIGIT_BITS = 16


def argsort_keys(key):
    """Stable permutation ``p`` such that ``dr.gather(type(key), key, p)``
    is non-decreasing (``key``: a flat 32-bit unsigned Dr.Jit array, lazy
    or evaluated; its evaluation joins any kernel the caller scheduled)."""
    UInt32 = type(key)
    n = dr.width(key)
    if n <= 1:
        return dr.arange(UInt32, n)
    buckets = 1 << DIGIT_BITS
    low = key & (buckets - 1)
    dr.eval(key, low)
    first = dr.detail.block_mkperm(low, n, buckets)
    high = dr.gather(UInt32, key, first) >> DIGIT_BITS
    dr.eval(high)
    second = dr.detail.block_mkperm(high, n, buckets)
    return dr.gather(UInt32, first, second)
