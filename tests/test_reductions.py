"""Scatter-reductions without contention (integrators.core.reductions)
against NumPy, and the places that must not pay a packet-local atomic."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from episcatter.kernels import kernel_log
from integrators.core.reductions import UNSHARED, block_counts


@pytest.mark.parametrize("block, blocks", [(1, 5), (7, 3), (16, 4), (6400, 3), (3, 0), (0, 4)])
def test_block_counts_equal_numpy(block, blocks):
    rng = np.random.default_rng(block + blocks)
    x = rng.integers(0, 2, block * blocks).astype(np.int32)
    out = np.asarray(block_counts(mi.Int32(x), block, blocks))
    expect = x.reshape(blocks, block).sum(1) if block else np.zeros(blocks, np.int32)
    np.testing.assert_array_equal(out, expect)


def test_unshared_add_equals_sequential_adds():
    """Targets no two lanes share (a permutation, and a partial one): the
    non-atomic add gives NumPy's float32 adds in order, exactly, twice over
    (as the packet-local atomic add a render uses does)."""
    rng = np.random.default_rng(3)
    for n, m in [(1, 1), (17, 40), (5000, 5000), (70001, 90000)]:
        target = rng.permutation(m)[:n].astype(np.uint32)
        v = rng.normal(size=n).astype(np.float32)
        start = rng.normal(size=m).astype(np.float32)
        # own buffers: a one-entry array from NumPy may be the NumPy buffer
        a, b, expect = mi.Float(start.copy()), mi.Float(start.copy()), start.copy()
        for _ in range(2):
            dr.scatter_reduce(dr.ReduceOp.Add, a, mi.Float(v), mi.UInt32(target),
                              mode=dr.ReduceMode.Local)
            dr.scatter_reduce(dr.ReduceOp.Add, b, mi.Float(v), mi.UInt32(target), mode=UNSHARED)
            expect[target] += v
        np.testing.assert_array_equal(np.asarray(b), expect)
        np.testing.assert_array_equal(np.asarray(a), expect)


@pytest.mark.skipif(not mi.variant().startswith("llvm"), reason="LLVM IR")
def test_the_tree_sweep_writes_its_sums_without_atomics():
    """The sweep (one lane per slice, 16 distinct slices per packet) writes
    each lane's own slots: a packet-local atomic there serialised the
    packet (a loop over its 16 targets per written value)."""
    from integrators.tree.partial_sum_tree import integrate_slices
    rng = np.random.default_rng(5)
    n, d, r, N = 40, 64, 30, 3
    D = rng.uniform(0, d, (n, r)).astype(np.float32)
    S = rng.uniform(0, r, (n, d)).astype(np.float32)
    A = rng.uniform(0, 1, (n, d, N)).astype(np.float32)
    B = rng.uniform(-1, 1, (n, r, N)).astype(np.float32)
    from integrators.template.base import SCATTER_EXPAND_THRESHOLD
    was = dr.expand_threshold()
    dr.set_expand_threshold(SCATTER_EXPAND_THRESHOLD)     # as during a render
    try:
        with kernel_log() as log:
            out = integrate_slices(D, S, A, B)
            dr.eval(out.array)
    finally:
        dr.set_expand_threshold(was)
    per_slice = [k for k in log.entries if k.get("size") == n]
    assert per_slice, [k.get("size") for k in log.entries]
    for k in per_slice:
        assert "atomic_local" not in k["ir"], "a packet-local atomic in a per-slice kernel"
    whole = [k for k in log.entries if k.get("size") == n * d]
    for k in whole:
        assert "atomic_local" not in k["ir"], "the modes' count per slice by atomics"


def test_the_closed_form_sweep_is_one_kernel_in_colour():
    """Slices without blockers (the closed form, A shared by the slices):
    the three channels' sums are one kernel (a plain scatter per channel
    would launch one kernel each)."""
    from integrators.tree.partial_sum_tree import integrate_slices
    rng = np.random.default_rng(6)
    n, d, r, N = 5, 16, 7, 2
    D = rng.uniform(0, d, (n, r)).astype(np.float32)
    S = np.full((n, d), np.inf, np.float32)                  # nothing blocks
    A = rng.uniform(0, 1, (1, d, 3, N)).astype(np.float32)
    B = rng.uniform(-1, 1, (n, r, 3, N)).astype(np.float32)
    with kernel_log() as log:
        out = integrate_slices(D, S, A, B)
        dr.eval(out.array)
    wide = [k for k in log.entries if k.get("size") == n * r]
    assert len(wide) == 1, [k.get("size") for k in log.entries]
