"""The device radix sort against NumPy's stable argsort (the oracle), on
keys that stress each digit, and its kernel count."""
from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from episcatter.kernels import kernel_log
from integrators.core.device_sort import argsort_keys


def _keys(kind: str, n: int, rng) -> np.ndarray:
    if kind == "uniform":
        return rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32)
    if kind == "equal":
        return np.full(n, 7, np.uint32)
    if kind == "high digit only":
        return rng.integers(0, 4, n).astype(np.uint32) << 30
    if kind == "both digits, few values":
        return ((rng.integers(0, 3, n).astype(np.uint32) << 16)
                | rng.integers(0, 3, n).astype(np.uint32))
    if kind == "extremes":
        return rng.choice(np.array([0, 1, 0xFFFF, 0x10000, 0xFFFFFFFF], np.uint32), n)
    if kind == "sorted":
        return np.sort(rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32))
    return np.sort(rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32))[::-1].copy()


@pytest.mark.parametrize("n", [0, 1, 2, 17, 4096, 70001])
@pytest.mark.parametrize("kind", ["uniform", "equal", "high digit only",
                                  "both digits, few values", "extremes", "sorted", "reversed"])
def test_argsort_keys_is_numpys_stable_argsort(n, kind):
    keys = _keys(kind, n, np.random.default_rng(n))
    got = np.asarray(argsort_keys(mi.UInt32(keys)), np.int64)
    np.testing.assert_array_equal(got, np.argsort(keys, kind="stable"))


def test_argsort_keys_is_two_kernels_joined_to_the_callers():
    """The key's kernel and the first digit are one kernel with what the
    caller scheduled; the second digit is the other."""
    import drjit as dr

    x = mi.Float(np.random.default_rng(1).random(5000).astype(np.float32))
    dr.eval(x)
    with kernel_log() as log:
        other = x * 2.0
        dr.schedule(other)
        order = argsort_keys(mi.UInt32(x * 1e6))
        dr.eval(order, other)
    assert log.launched == 2 + 1        # the two digits, and the final gather of the order
