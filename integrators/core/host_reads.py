"""Values of a frame that the host reads back to decide something (a size,
a range that sets a grid, a tolerance).

A reduction of an evaluated array is Dr.Jit's own (no JIT kernel); a
reduction of an expression first evaluates that expression, a kernel of
its own.  :func:`host_reductions` evaluates the expressions of several
reductions together -- one kernel per width -- and reads each result
back once.  Over arrays of a few thousand lanes (per row) that are
already evaluated, a copy to the host and NumPy (:func:`row_extremes`)
cost no kernel at all.
"""
from __future__ import annotations

import drjit as dr
import numpy as np


def host_reductions(*items) -> list:
    """``float(op(x)[0])`` (``bool`` for ``dr.any`` / ``dr.all``) of each
    ``(op, x)`` of ``items``, the ``x`` evaluated together first."""
    dr.eval(*(x for _, x in items))
    out = []
    for op, x in items:
        v = op(x)[0]
        out.append(bool(v) if op in (dr.any, dr.all) else float(v))
    return out


def row_extremes(values, mask=None, finite: bool = False) -> tuple[float, float]:
    """(min, max) of the evaluated array ``values`` over the lanes in
    ``mask`` (evaluated, or None: all; ``finite``: the finite values
    alone), ±inf where there are none, a NaN skipped as ``dr.min``/
    ``dr.max`` skip it: from host copies (no kernel; min and max are exact
    in any order)."""
    v = np.asarray(values)
    if mask is not None:
        v = v[np.asarray(mask, bool)]
    if finite:
        v = v[np.isfinite(v)]
    if not v.size:
        return float("inf"), float("-inf")
    return float(np.fmin.reduce(v)), float(np.fmax.reduce(v))
