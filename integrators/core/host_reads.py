"""Values of a frame that the host reads back to decide something (a size,
a range that sets a grid, a tolerance).

A reduction of an evaluated array is Dr.Jit's own (no JIT kernel); a
reduction of an expression first evaluates that expression, a kernel of
its own.  :func:`host_reductions` evaluates the expressions of several
reductions together -- one kernel per width -- and reads each result
back once.
"""
from __future__ import annotations

import drjit as dr


def host_reductions(*items) -> list:
    """``float(op(x)[0])`` (``bool`` for ``dr.any`` / ``dr.all``) of each
    ``(op, x)`` of ``items``, the ``x`` evaluated together first."""
    dr.eval(*(x for _, x in items))
    out = []
    for op, x in items:
        v = op(x)[0]
        out.append(bool(v) if op in (dr.any, dr.all) else float(v))
    return out
