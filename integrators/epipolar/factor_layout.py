"""The layout of the sweep's factor tensors ``A``, ``B``, ``L``: rows,
length, channels and whether a colour axis is present (DESIGN §3).
"""
from __future__ import annotations


def factor_layout(shape, with_n_axis: int, name: str = "factor"):
    """(rows ∈ {1, n}, length, C, has colour axis) of an A/B
    (``with_n_axis`` = 1: the trailing N axis) or L (0) shape, as
    :mod:`integrators.tree.partial_sum_tree` lists them ("Shapes")."""
    core = len(shape) - with_n_axis
    if core == 1 and with_n_axis:          # (d, N): shared by every slice
        return 1, shape[0], 1, False
    if core == 2:                          # (n|1, d[, N])
        return shape[0], shape[1], 1, False
    if core == 3:                          # (n|1, d, C[, N])
        return shape[0], shape[1], shape[2], True
    raise ValueError(f"{name} has unsupported shape {shape}")
