"""The host's reads of a frame's values (integrators.core.host_reads)
against Dr.Jit's own reductions."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest


if mi.variant() is None:
    mi.set_variant("llvm_ad_rgb")

from integrators.core.host_reads import host_reductions, row_extremes


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_row_extremes_are_drjits_masked_min_and_max(seed):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=257).astype(np.float32)
    v[rng.random(257) < 0.05] = np.nan
    v[3] = np.inf
    mask = rng.random(257) < 0.5
    x, m = mi.Float(v), mi.Bool(mask)
    dr.eval(x, m)
    for rows in (None, m):
        sel = x if rows is None else dr.select(rows, x, dr.inf)
        lo = host_reductions((dr.min, sel))[0]
        sel = x if rows is None else dr.select(rows, x, -dr.inf)
        hi = host_reductions((dr.max, sel))[0]
        assert row_extremes(x, rows) == (lo, hi)


def test_row_extremes_of_no_lanes_are_infinite():
    x = mi.Float([1.0, 2.0])
    assert row_extremes(x, mi.Bool([False, False])) == (float("inf"), float("-inf"))
