"""Scatter-reductions by how their lanes share targets.

Dr.Jit's default reduction on the CPU (``ReduceMode.Local``, with the
expand threshold a render sets) pre-reduces the lanes of a packet that hit
the same entry: a loop over the packet's distinct targets, so a packet of
16 lanes with 16 distinct targets pays 16 rounds of it plus 16 atomics.
Two cases avoid it:

- :data:`UNSHARED`: every entry is the target of at most one lane of the
  kernel (a lane's own slot of a map, written once per term or channel):
  a plain read-modify-write, no atomics (``ReduceMode.NoConflicts``; the
  caller guarantees the uniqueness).
- :func:`block_counts`: counts over contiguous blocks of equal size (a
  row-major map's rows): Dr.Jit's block reduction over the evaluated
  array, no scatter at all.
"""
from __future__ import annotations

import drjit as dr

#: mode of a scatter-reduction whose targets no two lanes share
UNSHARED = dr.ReduceMode.NoConflicts


def block_counts(values, block: int, blocks: int):
    """Sum of ``values`` (an Int or UInt array of ``blocks·block`` entries,
    evaluated here) over each of its ``blocks`` contiguous blocks of
    ``block`` entries; zeros where the array is empty."""
    if blocks * block == 0:
        return dr.zeros(type(values), blocks)
    return dr.block_reduce(dr.ReduceOp.Add, values, block, mode="evaluated")
