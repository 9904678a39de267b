"""Tabulated Nyström extensions of the separated kernel (Baran et al. 2010, §6).

The separated kernel K(γ, β) ≈ Σ_i a_i(γ) b_i(β) is extended exactly from its
64-point SVD grid (:func:`integrators.epipolar.kernel.svd.extend_nystrom`): every
a_i or b_i value is a 64-term sum of kernel evaluations.  Each function
depends on one scalar (the light ray's γ, or the query's β), while there are
s·d light rays and about a million queries; so when the lanes far outnumber
``KERNEL_TABLE`` the sums are evaluated on ``KERNEL_TABLE`` points uniform in
v = log(1 + c·(x − lo)) (c: the rate of the kernel's fastest decay, the same
warp as the SVD grids, so each term is smooth in v) and interpolated
linearly: error ≈ (Δv)²/8 · |f''|, measured 2e-7 of a term's range for the
leading terms and up to 1.4e-4 for the last, most oscillating ones (whose
singular values are the smallest); rendered images agree with the direct
sums to relMSE < 1e-6 (``tests/test_kernel_table.py``), for a 64/2 = 32×
cheaper stage.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import drjit as dr
import mitsuba as mi
import numpy as np

from ...core.opaque import floats, opaque_scalar, scalar


def nystrom_sums(n_lanes: int, weights: np.ndarray, term) -> list:
    """Σ_k term(k) · weights[k, i] per lane, for each column i, in one
    Dr.Jit loop: the exact (Nyström) extension of a separated kernel
    (:func:`integrators.epipolar.kernel.svd.separate_sampled_kernel`; both light
    kinds); ``term(k)`` gives the lanes' kernel values at grid point k."""
    K, N = weights.shape
    W = [floats(weights[:, i]) for i in range(N)]
    n_k = opaque_scalar(mi.UInt32, K)

    def body(k, acc):
        e = term(k)
        return k + 1, tuple(a + e * dr.gather(mi.Float, w, k) for a, w in zip(acc, W))

    _, acc = dr.while_loop(state=(mi.UInt32(0), tuple(dr.zeros(mi.Float, n_lanes)
                                                      for _ in range(N))),
                           cond=lambda k, acc: k < n_k, body=body)
    return list(acc)


#: points of a tabulated Nyström sum
KERNEL_TABLE = 4096


@dataclass(frozen=True, eq=False)
class TermTable:
    """The N terms at the table's nodes (uniform in v = log(1 + c·(x − lo)),
    ``v ∈ [0, v_hi]``): :func:`term_table`, read by :meth:`lookup`."""
    lo: float
    c: float
    v_hi: float
    values: list

    def lookup(self, x: mi.Float) -> list:
        """The terms at ``x``, lerped between the nodes.  ``lo``, ``c`` and
        the table's scale enter as kernel parameters (opaque), not
        literals: another frame reuses its kernel."""
        u = (dr.log(1.0 + scalar(self.c) * dr.maximum(x - scalar(self.lo), 0.0))
             * scalar((KERNEL_TABLE - 1) / self.v_hi))
        i0 = mi.UInt32(dr.clip(dr.floor(u), 0, KERNEL_TABLE - 2))
        f = dr.clip(u - mi.Float(i0), 0.0, 1.0)
        return [dr.lerp(dr.gather(mi.Float, t, i0), dr.gather(mi.Float, t, i0 + 1), f)
                for t in self.values]


def term_table(lo: float, hi: float, c: float, terms_at: Callable[[mi.Float], list]) -> TermTable:
    """The table of :func:`tabulated_terms` over ``[lo, hi]``, its values not
    yet evaluated (the caller evaluates them, with other tables: one
    kernel)."""
    lo, hi = float(lo), float(hi)
    c = max(float(c), 1e-6 / max(hi - lo, 1e-30))
    v_hi = math.log1p(c * (hi - lo))
    if not v_hi > 0.0:
        v_hi = 1e-6
    v_tab = np.linspace(0.0, v_hi, KERNEL_TABLE)
    return TermTable(lo, c, v_hi, terms_at(floats(lo + np.expm1(v_tab) / c)))


def tabulated_terms(x: mi.Float, lo: float, hi: float, c: float,
                    terms_at: Callable[[mi.Float], list], lanes: int | None = None,
                    table: Callable[[], TermTable] | None = None) -> list:
    """``terms_at(x)`` (a list of N Floats, one per term) at every lane of
    ``x`` ∈ [lo, hi]: directly when there are fewer than 4·``KERNEL_TABLE``
    lanes, else from a table uniform in v = log(1 + c·(x − lo)), lerped
    (:class:`TermTable`; ``table``: gives it evaluated, e.g. kept by the
    caller, else :func:`term_table` made here).  ``lanes``: the count that
    decides (default: ``x``'s; a partial render's rows pass the whole
    frame's, so that they get the full render's values)."""
    if (dr.width(x) if lanes is None else lanes) < 4 * KERNEL_TABLE:
        return terms_at(x)
    if table is not None:
        return table().lookup(x)
    tab = term_table(lo, hi, c, terms_at)
    dr.eval(*tab.values)    # the whole table in one kernel (a gather would evaluate each term)
    return tab.lookup(x)
