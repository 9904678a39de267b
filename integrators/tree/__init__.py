"""Stages of ``epipolar_tree`` (Baran et al. 2010) after the shared epipolar
rectification (:mod:`integrators.epipolar`): :mod:`.partial_sum_tree`, the
incremental partial-sum sweep of every rectified slice, and
:mod:`.partial_sum_reference`, its NumPy oracle.

Fast path (:func:`.partial_sum_tree.integrate_slices`)
------------------------------------
1. Modes that can act (w ≠ 0, γ < d_count, ⌈β⌉ < r_count) are counted per
   slice.  Slices without any (nothing blocks inside the view) skip the tree:
   out = Δγ Σ_i B_i lerp(C_i(k0), C_i(k0+1), f) with C the cumulative sum of
   A·L -- computed once for all slices when A is shared and L is absent,
   else per slice in lane-local memory.
2. For the other slices a counting-sort kernel (one lane per slice, bucket
   histogram in local memory) writes the updates sorted by (β, γ, m) into one
   flat list per slice (the ``termination_depths`` of Fig. 6; deterministic).
3. The sweep kernel (one lane per slice) holds a Fenwick tree [Fenwick 1994]
   of the leaves and their visibilities in lane-local memory, walks β in a
   symbolic loop, applies the fractional updates (§7) whose β_m ≤ β and
   answers the two prefix queries (Fig. 6; the second as P(k0) + f·b[k0],
   the "complete lowest level" of §5).
"""
