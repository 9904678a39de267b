"""The tabulated Nyström sums (integrators.epipolar.kernel.table) against the direct
64-term sums: per term, and in whole renders with more lanes than the table
threshold (directional, point and textured spot light, HG phase)."""
import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from episcatter.metrics import relmse_absolute as relmse
from integrators.epipolar.kernel import table as kernel_table
from integrators.epipolar.kernel.separation import exp_kernel_sum, separate_channel
from tests.conftest import scene_dict


@pytest.mark.parametrize("sigma_t", [1e-3, 0.3, 30.0])
def test_tabulated_directional_terms_match_direct_sums(sigma_t):
    """a_i(γ) and b_i(tan β/2) of the directional kernel: lerped table vs
    the exact Nyström sums at 50,000 random points, thin to thick media."""
    g_max, b_lo, b_hi = 40.0, 0.05, 3.0
    g_grid, x_grid, WA, WB = separate_channel(sigma_t, g_max, b_lo, b_hi, 0, 1e-3)
    rng = np.random.default_rng(1)
    x_lo, x_hi = math.tan(b_lo / 2), math.tan(b_hi / 2)
    cases = [(mi.Float(rng.uniform(0, g_max, 50000).astype(np.float32)), 0.0, g_max,
              sigma_t * float(np.max(x_grid)), x_grid, WA),
             (mi.Float(rng.uniform(x_lo, x_hi, 50000).astype(np.float32)), x_lo, x_hi,
              sigma_t * g_max, g_grid, WB)]
    for x, lo, hi, c, table, W in cases:
        def direct(v):
            return exp_kernel_sum(v, table, W, sigma_t)
        fast = kernel_table.tabulated_terms(x, lo, hi, c, direct)
        exact = direct(x)
        for f, e in zip(fast, exact):
            f, e = np.array(f, np.float64), np.array(e, np.float64)
            # measured 2e-7 (leading terms) … 1.4e-4 (the last, most oscillating
            # ones, whose singular values are smallest) of each term's range
            assert np.max(np.abs(f - e)) <= 3e-4 * np.max(np.abs(e)) + 1e-12


@pytest.mark.parametrize("light,phase", [("directional", None),
                                         ("point", {"type": "hg", "g": 0.5}),
                                         ("spot_textured", {"type": "hg", "g": -0.4})])
@pytest.mark.parametrize("integrator", ["epipolar_tree", "fourier_filter"])
def test_tabulated_renders_match_direct_sums(monkeypatch, light, phase, integrator):
    """160×120 (19,200 queries > 4·KERNEL_TABLE: the table is used) against
    the same render with the table switched off."""
    scene = mi.load_dict(scene_dict(light=light, phase=phase, res=(160, 120)))
    props = {"type": integrator, "weights": "exact"} if integrator == "fourier_filter" \
        else {"type": integrator}
    fast = np.array(mi.render(scene, integrator=mi.load_dict(props)))
    monkeypatch.setattr(kernel_table, "KERNEL_TABLE", 1 << 30)
    direct = np.array(mi.render(scene, integrator=mi.load_dict(props)))
    assert np.all(np.isfinite(fast))
    assert relmse(fast, direct) < 1e-6
