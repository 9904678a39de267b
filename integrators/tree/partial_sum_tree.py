"""Incremental partial-sum (Fenwick half-)tree integration of epipolar slices.

Baran et al. 2010, "A Hierarchical Volumetric Shadow Algorithm for Single
Scattering", §4-§7 (Eq. 3, Fig. 6).  This module is the numeric core of the
``epipolar_tree`` method: it knows nothing about scenes or cameras, only about
rectified slices.

Rectified slice α (§3)
----------------------
A slice has ``d`` light rays (leaves, index γ = 0..d-1, leaf γ spans the
light-ray coordinate interval [γ, γ+1) of width Δγ) and ``r`` view rays
(β = 0..r-1, in the sweep order of Fig. 6: from the light away).  Inputs:

``D[β]``
    Camera depth of view ray β as a *fractional light-ray index*: the view
    ray crosses light rays 0..D[β].  Clamped to [0, d]; +inf means "leaves
    the slice" (= d), NaN counts as 0.
``S`` (blockers)
    For each light ray γ, one or more *modes* (β_m, w_m) (§7, Fig. 7): the
    mode removes the fraction w_m of leaf γ for every view ray β ≥ β_m.
    A plain shadow map is the special case of one mode of weight 1 per light
    ray, i.e. Eq. 3's "light ray γ is lit at β iff S[γ] > β".  β_m may be
    real (a blocker between two view rays): it then acts from view ray
    ⌈β_m⌉ on.  β_m ≤ 0 blocks before the first view ray, β_m ≥ r (or +inf,
    NaN) never blocks, w_m = 0 is no update.  Weights of one light ray
    normally sum to ≤ 1; nothing enforces it (the sum is taken literally).
``A[γ, i]``, ``B[β, i]``
    The separated integrand I(γ, β) ≈ Σ_{i<N} A_i(γ) B_i(β) (Eq. 4, §6),
    see :mod:`integrators.epipolar.kernel.svd`.  The singular values are folded
    into ``B``.
``L[γ]`` (optional)
    A per-light-ray factor multiplied into the leaves, e.g. a textured
    light's L̃_in(α, γ) (§6) or the light-side attenuation
    e^{-σt h(α, γ)} of a directional light (DESIGN §1).

Exact semantics (what
:func:`~integrators.tree.partial_sum_reference.integrate_slices_reference` computes)
------------------------------------------------------------------
With visibility of leaf γ at view ray β

    V(γ, β) = 1 − Σ_{modes m of γ with w_m ≠ 0 and ⌈β_m⌉ ≤ β} w_m,

i.e. **a mode at β_m is applied before the query of view ray β_m** (Fig. 4:
"set to zero ... before computing the integral for view ray β + 1"), leaves
b_i[γ](β) = A_i(γ) L(γ) V(γ, β), and D_c = clip(D[β], 0, d):

    out[β] = Δγ · Σ_i B_i(β) · Σ_{γ<d} b_i[γ](β) · clip(D_c − γ, 0, 1).

The coverage weight clip(D_c − γ, 0, 1) (the view ray covers the part of
leaf γ in front of its depth) is exactly the lerp of two prefix queries of
Fig. 6: with k0 = min(⌊D_c⌋, d − 1), f = D_c − k0 and P(k) = Σ_{γ<k} b[γ],
out = Δγ Σ_i B_i · lerp(P_i(k0), P_i(k0 + 1), f) = Δγ Σ_i B_i (P_i(k0) + f b_i[k0]).
For integer D this is Eq. 3's Σ_{γ<D[β]}.

Shapes (NumPy arrays or Dr.Jit tensors; ``n`` slices, padded sizes r, d)
-----------------------------------------------------------------------
- ``D``: (n, r) float.
- ``S_modes``: (n, d) blocker β (one full-weight mode per light ray), or a
  :class:`~integrators.epipolar.blockers.BlockerModes` of (n, d, M) arrays ``beta`` and
  ``weight`` (build it
  from flat (slice, gamma, beta, weight) lists with
  :meth:`~integrators.epipolar.blockers.BlockerModes.from_flat`).
- ``A``: (d, N), (n|1, d, N) or, coloured, (n|1, d, C, N).
- ``B``: (r, N), (n|1, r, N) or, coloured, (n|1, r, C, N).
- ``L``: None, (n|1, d) or (n|1, d, C).
- ``r_count``, ``d_count``: (n,) ints, the real sizes of ragged slices
  (default: r and d).  View rays β ≥ r_count give 0; leaves γ ≥ d_count do
  not exist (D is clamped to d_count, their modes are ignored).
- Result: (n, r) float32, or (n, r, C) when any of A, B, L has a colour
  axis (size-1 colour axes broadcast).  Colour is integrated in one sweep:
  the tree stores C·N-vectors (§6 "the tree stores N-dimensional vectors";
  §10.3 textured light with three channels); when d·(C·N + 1) exceeds the
  local-memory budget the C·N components are split over several sweeps.

The fast path (:func:`integrate_slices`) is described in
:mod:`integrators.tree`.

Limits: d ≤ 32 767 light rays (the tree of d·K entries plus the d
visibilities live in lane-local memory, :data:`LOCAL_BUDGET`; K = C·N is
split over several sweeps when it does not fit), r ≤ 65 535 view rays.
Kernels are compiled per (M, N, C, broadcast flags, rounded local sizes);
timings must be taken on a second call.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify._dr import aligned

from ..core.opaque import Divisor, opaque_scalar
from ..core.reductions import UNSHARED, block_counts
from ..epipolar.blockers import BlockerModes
from ..epipolar.factor_layout import factor_layout


class _VariantTypes:
    """The active variant's Dr.Jit types without AD (the kernels are not
    differentiated), looked up at every use: nothing about the variant is
    bound when the module is imported."""

    @property
    def Float(self):
        return dr.detached_t(mi.Float)

    @property
    def Int(self):
        return dr.detached_t(mi.Int32)

    @property
    def TensorXf(self):
        return dr.detached_t(mi.TensorXf)


#: ``jt.Float``, ``jt.Int``, ``jt.TensorXf``: the active variant's types
jt = _VariantTypes()

#: Max. entries of one lane-local array (a hard Dr.Jit limit is 65 535).
LOCAL_ARRAY_LIMIT = 65535
#: Budget for all lane-local arrays of one kernel, in 32-bit entries.  The
#: LLVM backend keeps them on the worker thread's stack once per SIMD packet
#: (16 lanes with AVX-512), so 65 535 entries ≈ 4 MiB; twice that overflowed
#: the 8 MiB stack here (segmentation fault, not an exception).
LOCAL_BUDGET = 65535


def _shape_of(x) -> tuple:
    return tuple(x.shape) if hasattr(x, "shape") else np.shape(x)


def to_numpy(x, dtype=np.float64) -> np.ndarray:
    return np.asarray(np.array(x), dtype=dtype)


def _flat(x, dtype):
    """Flat Dr.Jit array (``Float`` or ``Int``) of a NumPy array/Dr.Jit tensor."""
    if dr.is_array_v(x):
        return dtype(dr.detach(x.array if dr.is_tensor_v(x) else x))
    np_type = np.float32 if dtype is jt.Float else np.int32
    return dtype(aligned(x, np_type))


def split_modes(S_modes):
    """(beta, weight-or-None, shape (n, d, M)) of either blocker form."""
    if isinstance(S_modes, BlockerModes):
        shape = _shape_of(S_modes.beta)
        if len(shape) != 3 or _shape_of(S_modes.weight) != shape:
            raise ValueError("BlockerModes beta and weight must both be (n, d, M)")
        return S_modes.beta, S_modes.weight, shape
    shape = _shape_of(S_modes)
    if len(shape) != 2:
        raise ValueError(f"S must be (n, d) or BlockerModes, got shape {shape}")
    return S_modes, None, (shape[0], shape[1], 1)


def _factor_layout(shape, name, n, length, with_n_axis):
    """(rows ∈ {1, n}, C, has colour axis) of A/B/L, checked against n
    slices and ``length`` (d or r)."""
    rows, ln, C, colour = factor_layout(shape, with_n_axis, name)
    if rows not in (1, n) or ln != length:
        raise ValueError(f"{name} shape {shape} does not match n={n}, length {length}")
    return rows, C, colour


class _Record:
    """Plain attribute record.  Deliberately not a dataclass/NamedTuple:
    ``@dr.syntax`` loops treat those as PyTrees, would make them loop state
    and try to assign their fields."""

    def __init__(self, *values, **named):
        for name, value in zip(self.__annotations__, values):
            setattr(self, name, value)
        for name, value in named.items():
            setattr(self, name, value)


class _Layout(_Record):
    """Sizes of one problem.  M, N, C and the colour/broadcast flags are
    baked into the kernels (unrolled); d and r reach the kernels' index
    arithmetic as opaque parameters (``_Problem.d_o``, ``r_o``)."""

    n: int          # slices
    r: int          # padded view rays per slice
    d: int          # padded light rays per slice
    M: int          # mode slots per light ray
    N: int          # separated terms
    C: int          # colour channels of the result
    coloured: bool  # whether the result has a colour axis
    nA: int
    CA: int
    nB: int
    CB: int
    nL: int         # 0: no L
    CL: int


class _Problem(_Record):
    lay: _Layout
    D: Float        # (n, r) as given (NaN read as 0), not yet clamped per slice
    beta: Int       # (n, d, M) ⌈β_m⌉ in [0, r]; r = never
    weight: Float   # (n, d, M), 0 where the mode cannot act
    A: Float
    B: Float
    L: Float | None
    r_count: "_SliceCounts"    # (n,) view rays per slice
    d_count: "_SliceCounts"    # (n,) light rays per slice
    d_o: Int        # d and r as opaque kernel parameters, so that index
    r_o: Int        # arithmetic does not recompile for every resolution
    updates: Int    # (n,) modes per slice that act inside the view (w ≠ 0)


class _SliceCounts:
    """Per-slice counts (n,) clamped to [0, ``default``], read where they
    are used (:meth:`at`): the given array as it is (converted and clamped
    at each reader's lanes: no kernel of its own), or ``default`` (a
    frame's size, opaque) for every slice where none is given."""

    def __init__(self, x, n: int, default: int):
        self.default = opaque_scalar(jt.Int, default)      # a frame's size: not a literal
        self.src = None
        if x is not None:
            src = (dr.detach(x.array if dr.is_tensor_v(x) else x) if dr.is_array_v(x)
                   else jt.Int(aligned(x, np.int32)))
            if dr.width(src) != n:
                raise ValueError(f"per-slice counts must have length {n}")
            self.src = src

    def at(self, slices):
        """The counts of ``slices`` (per lane)."""
        if self.src is None:
            return dr.zeros(jt.Int, dr.width(slices)) + self.default
        c = jt.Int(dr.gather(type(self.src), self.src, slices))
        return dr.clip(c, 0, self.default)


def problem_layout(D, S_modes, A, B, L) -> _Layout:
    """Validate the shapes (module docstring) and return the sizes."""
    if len(_shape_of(D)) != 2:
        raise ValueError(f"D must be (n, r), got {_shape_of(D)}")
    n, r = _shape_of(D)
    _, _, (nS, d, M) = split_modes(S_modes)
    if nS != n:
        raise ValueError(f"S has {nS} slices, D has {n}")
    A_shape, B_shape = _shape_of(A), _shape_of(B)
    if not A_shape or A_shape[-1] != (B_shape[-1] if B_shape else None):
        raise ValueError(f"A {A_shape} and B {B_shape} need the same last axis N")
    N = A_shape[-1]
    nA, CA, colA = _factor_layout(A_shape, "A", n, d, 1)
    nB, CB, colB = _factor_layout(B_shape, "B", n, r, 1)
    nL, CL, colL = (0, 1, False) if L is None else _factor_layout(
        _shape_of(L), "L", n, d, 0)
    C = max(CA, CB, CL)
    if any(c not in (1, C) for c in (CA, CB, CL)):
        raise ValueError(f"colour axes {CA}, {CB}, {CL} do not broadcast")
    lay = _Layout(n, r, d, M, N, C, colA or colB or colL, nA, CA, nB, CB, nL, CL)
    if r > LOCAL_ARRAY_LIMIT:
        raise ValueError(f"r = {r} view rays exceed {LOCAL_ARRAY_LIMIT}")
    return lay


def _prepare(D, S_modes, A, B, L, r_count, d_count) -> _Problem:
    """Bring every input into flat Dr.Jit arrays (shapes checked by problem_layout)."""
    lay = problem_layout(D, S_modes, A, B, L)
    n, r, d, M = lay.n, lay.r, lay.d, lay.M
    beta_in, weight_in, _ = split_modes(S_modes)
    r_cnt, d_cnt = _SliceCounts(r_count, n, r), _SliceCounts(d_count, n, d)

    # Modes: ⌈β⌉ clamped to [0, r] (r = never), and weight 0 for modes that
    # cannot act in their slice (γ ≥ d_count, ⌈β⌉ ≥ r_count, NaN β).
    bf = _flat(beta_in, jt.Float)
    bf = dr.select(dr.isnan(bf), dr.inf, bf)
    r_o, d_o = opaque_scalar(jt.Int, r), opaque_scalar(jt.Int, d)   # a frame's sizes, not literals
    beta = jt.Int(dr.ceil(dr.clip(bf, 0.0, jt.Float(r_o))))
    weight = dr.ones(jt.Float, dr.width(beta)) if weight_in is None else _flat(weight_in, jt.Float)
    j = dr.arange(jt.Int, n * d * M)
    s, g = Divisor(d * M).div(j), Divisor(d).divmod(j // M)[1]
    acts = (g < d_cnt.at(s)) & (beta < r_cnt.at(s))
    weight = dr.select(acts, weight, 0.0)
    beta = dr.select(weight != 0, beta, r_o)
    # the modes and, per slice, the count of those acting: a block sum over
    # the slice's d·M contiguous modes (an atomic count per slice serialises
    # the lanes of a packet, which all hit the same slice)
    acting = jt.Int(weight != 0)
    dr.eval(beta, weight, acting)
    updates = block_counts(acting, d * M, n)
    Lf = None if L is None else _flat(L, jt.Float)
    return _Problem(lay, _flat(D, jt.Float), beta, weight, _flat(A, jt.Float),
                    _flat(B, jt.Float), Lf, r_cnt, d_cnt, d_o, r_o, updates)


def _components(lay: _Layout, budget_per_leaf: int):
    """The C·N (channel c, term i) pairs, in chunks whose local arrays fit."""
    comps = [(c, i) for c in range(lay.C) for i in range(lay.N)]
    k = max(1, min(len(comps), budget_per_leaf))
    return [comps[j:j + k] for j in range(0, len(comps), k)]


def _local_size(n: int) -> int:
    """Local array sizes rounded up (fewer distinct kernels to compile)."""
    return max(256, -(-n // 256) * 256)


# --------------------------------------------------------------------------
# Gathers shared by the kernels
# --------------------------------------------------------------------------

def _leaf(p: _Problem, s, g, comps):
    """Leaf values A_i(γ)·L(γ) of slice ``s``, light ray ``g`` (§6)."""
    lay = p.lay
    rowA = s * p.d_o + g if lay.nA > 1 else g
    rowL = s * p.d_o + g if lay.nL > 1 else g
    out = []
    for c, i in comps:
        a = dr.gather(jt.Float, p.A, (rowA * lay.CA + c % lay.CA) * lay.N + i)
        if p.L is not None:
            a = a * dr.gather(jt.Float, p.L, rowL * lay.CL + c % lay.CL)
        out.append(a)
    return out


def _view_factor(p: _Problem, s, beta, comps):
    """B_i(β) of slice ``s``, view ray ``beta``."""
    lay = p.lay
    row = s * p.r_o + beta if lay.nB > 1 else beta
    return [dr.gather(jt.Float, p.B, (row * lay.CB + c % lay.CB) * lay.N + i)
            for c, i in comps]


def _depth_split(p: _Problem, s, beta, d_s):
    """(k0, f) of Fig. 6: D clamped to [0, d_s], k0 = min(⌊D⌋, d_s − 1) ≥ 0."""
    D = dr.gather(jt.Float, p.D, s * p.r_o + beta)
    Dc = dr.clip(dr.select(dr.isnan(D), 0.0, D), 0.0, jt.Float(d_s))
    k0 = dr.maximum(dr.minimum(jt.Int(dr.floor(Dc)), d_s - 1), 0)
    return k0, Dc - jt.Float(k0)


def _accumulate(p: _Problem, out, s, beta, comps, q, active=True, add=True):
    """out[s, β, c] += Σ_{i in chunk} B_i(β) q_i, without atomics (each lane
    owns its slots: an atomic add serialises the 16 distinct slots of a
    packet); with ``add=False`` the slot is written, not added to -- the
    first chunk of components inside a symbolic loop (one kernel whatever
    it scatters), whose slots nothing wrote before."""
    Bv = _view_factor(p, s, beta, comps)
    per_channel = {}
    for (c, _), b, qi in zip(comps, Bv, q):
        per_channel[c] = per_channel.get(c, 0) + b * qi
    for c, v in per_channel.items():
        slot = (s * p.r_o + beta) * p.lay.C + c
        if add:
            dr.scatter_reduce(dr.ReduceOp.Add, out, v, slot, active, mode=UNSHARED)
        else:
            dr.scatter(out, v, slot, active)


# --------------------------------------------------------------------------
# Step 1: which slices need the tree
# --------------------------------------------------------------------------

# --------------------------------------------------------------------------
# Step 2: termination lists (Fig. 6), counting sort by β, one lane per slice
# --------------------------------------------------------------------------

class _Updates(_Record):
    """Per slice, the acting modes sorted by (β, γ, m): a CSR list."""

    begin: Int      # (lanes,) first entry of the lane's slice
    end: Int        # (lanes,) one past its last entry
    gamma: Int      # (total,)
    beta: Int
    weight: Float


@dr.syntax
def _bucket_kernel(p: _Problem, slices, begin, hist_size, gamma_out, beta_out, w_out):
    lay = p.lay
    r_s = p.r_count.at(slices)
    d_s = p.d_count.at(slices)
    hist = dr.alloc_local(jt.Int, hist_size)
    r_s = dr.minimum(r_s, jt.Int(hist_size))      # size literal: part of the kernel hash
    b = jt.Int(0)
    while b < r_s:
        hist[b] = jt.Int(0)
        b += 1
    g = jt.Int(0)
    while g < d_s:                       # histogram of ⌈β_m⌉
        for m in range(lay.M):
            bm = dr.gather(jt.Int, p.beta, (slices * p.d_o + g) * lay.M + m)
            if bm < r_s:
                hist[bm] = hist[bm] + 1
        g += 1
    b = jt.Int(0)
    run = jt.Int(begin)
    while b < r_s:                       # exclusive scan → write positions
        h = hist[b]
        hist[b] = run
        run += h
        b += 1
    g = jt.Int(0)
    while g < d_s:                       # stable placement
        for m in range(lay.M):
            j = (slices * p.d_o + g) * lay.M + m
            bm = dr.gather(jt.Int, p.beta, j)
            if bm < r_s:
                pos = hist[bm]
                hist[bm] = pos + 1
                dr.scatter(gamma_out, g, pos)
                dr.scatter(beta_out, bm, pos)
                dr.scatter(w_out, dr.gather(jt.Float, p.weight, j), pos)
        g += 1


def _termination_lists(p: _Problem, slices: jt.Int, counts: np.ndarray) -> _Updates:
    """``counts``: every slice's acting modes (host copy of ``p.updates``);
    ``slices``: those with a tree."""
    rows = np.asarray(slices, np.int64)
    # the slices without modes hold none: offsets over all slices, read at these
    offsets = np.cumsum(counts, dtype=np.int64) - counts
    begin = jt.Int(aligned(offsets[rows], np.int32))
    end = jt.Int(aligned(offsets[rows] + counts[rows], np.int32))
    total = int(counts.sum())
    gamma, beta = dr.zeros(jt.Int, max(total, 1)), dr.zeros(jt.Int, max(total, 1))
    weight = dr.zeros(jt.Float, max(total, 1))
    # Scatter targets must be real buffers before the symbolic loop: a
    # second scatter into a still-literal zeros() array in the same loop
    # body fails with "remains dirty".
    dr.make_opaque(gamma, beta, weight)
    if total:
        hist_size = min(_local_size(p.lay.r), LOCAL_ARRAY_LIMIT)
        _bucket_kernel(p, slices, begin, hist_size, gamma, beta, weight)
        dr.eval(gamma, beta, weight)
    return _Updates(begin, end, gamma, beta, weight)


# --------------------------------------------------------------------------
# Step 3: the sweep (Fig. 6) with a Fenwick half-tree in lane-local memory
# --------------------------------------------------------------------------

def _tree_index(i, k, K):
    """Local-memory slot of component k of Fenwick node i (1-based)."""
    return i * K + k


@dr.syntax
def _sweep_kernel(p: _Problem, slices, upd: _Updates, comps, tree_size, leaf_size, out,
                  add):
    """INTEGRATESLICE (Fig. 6) for the slices ``slices``, components ``comps``.

    Node i (1-based) of the Fenwick tree [Fenwick 1994] holds Σ b[γ] over γ
    in (i − lowbit(i), i] -- the left children of Fig. 5 only (half-tree);
    ``vis[γ]`` is V(γ, β) of the current β (the complete lowest level of §5,
    which makes the second query of the lerp P(k0) + f·b[k0]).

    One function on purpose: moving the loops that write the lane-local
    arrays into helper functions or methods gave silently wrong sums or
    "computation references variables from a loop that was optimized away"
    with Dr.Jit 1.5."""
    K = len(comps)
    r_s = p.r_count.at(slices)
    d_s = p.d_count.at(slices)
    tree = dr.alloc_local(jt.Float, tree_size)
    vis = dr.alloc_local(jt.Float, leaf_size)
    # size literals: part of the kernel hash (Dr.Jit 1.5 omits local array sizes)
    d_s = dr.minimum(d_s, dr.minimum(jt.Int(leaf_size), jt.Int(tree_size // K - 1)))

    # BUILD-TREE in O(d): leaves (and vis = 1), then each node adds itself
    # to its parent.
    i = jt.Int(1)
    while i <= d_s:
        vis[i - 1] = jt.Float(1.0)
        a = _leaf(p, slices, i - 1, comps)
        for k in range(K):
            tree[_tree_index(i, k, K)] = a[k]
        i += 1
    i = jt.Int(1)
    while i <= d_s:
        parent = i + (i & -i)
        if parent <= d_s:
            for k in range(K):
                tree[_tree_index(parent, k, K)] = (
                    tree[_tree_index(parent, k, K)] + tree[_tree_index(i, k, K)])
        i += 1

    beta = jt.Int(0)
    ptr = jt.Int(upd.begin)
    while beta < r_s:
        # Fractional updates of the light rays that terminate at β (§7).
        pending = ptr < upd.end
        bm = dr.gather(jt.Int, upd.beta, ptr, pending)
        while pending & (bm <= beta):
            g = dr.gather(jt.Int, upd.gamma, ptr)
            w = dr.gather(jt.Float, upd.weight, ptr)
            vis[g] = vis[g] - w
            a = _leaf(p, slices, g, comps)
            delta = [-w * a[k] for k in range(K)]
            i = g + 1
            while i <= d_s:              # UPDATE-TREE
                for k in range(K):
                    tree[_tree_index(i, k, K)] = tree[_tree_index(i, k, K)] + delta[k]
                i += i & -i
            ptr += 1
            pending = ptr < upd.end
            bm = dr.gather(jt.Int, upd.beta, ptr, pending)

        # QUERY-TREE at ⌊D⌋, then the next leaf for the lerp (Fig. 6).
        k0, f = _depth_split(p, slices, beta, d_s)
        q = [jt.Float(0.0) for _ in range(K)]
        i = jt.Int(k0)
        while i > 0:
            q = [q[k] + tree[_tree_index(i, k, K)] for k in range(K)]
            i = i & (i - 1)
        a0 = _leaf(p, slices, k0, comps)
        fv = dr.select(d_s > 0, f * vis[k0], 0.0)
        q = [q[k] + fv * a0[k] for k in range(K)]
        _accumulate(p, out, slices, beta, comps, q, add=add)
        beta += 1


def _run_tree(p: _Problem, slices: jt.Int, counts: np.ndarray, out: jt.Float):
    upd = _termination_lists(p, slices, counts)
    leaf_size = _local_size(p.lay.d)
    per_leaf = (LOCAL_BUDGET - leaf_size) // (p.lay.d + 1)
    if per_leaf < 1:
        raise ValueError(f"d = {p.lay.d} light rays do not fit in lane-local memory")
    for chunk, comps in enumerate(_components(p.lay, per_leaf)):
        tree_size = _local_size((p.lay.d + 1) * len(comps))
        _sweep_kernel(p, slices, upd, comps, min(tree_size, LOCAL_ARRAY_LIMIT),
                      leaf_size, out, chunk > 0)
        dr.eval(out)


# --------------------------------------------------------------------------
# Skip work: slices without blockers need no tree (closed form)
# --------------------------------------------------------------------------

def _closed_form_shared(p: _Problem, slices: jt.Int, out: jt.Float):
    """A shared by all slices, no L: cumulative sums of A computed once,
    gathered at D for every (slice, β) lane."""
    lay = p.lay
    comps = [(c, i) for c in range(lay.C) for i in range(lay.N)]
    gam = dr.arange(jt.Int, lay.d + 1)
    cum = [dr.prefix_sum(dr.select(gam < lay.d,
                                   _leaf(p, jt.Int(0), dr.minimum(gam, lay.d - 1), [ci])[0],
                                   0.0)) for ci in comps]
    lane = dr.arange(jt.Int, dr.width(slices) * lay.r)
    s = dr.gather(jt.Int, slices, lane // p.r_o)
    beta = lane % p.r_o
    active = beta < p.r_count.at(s)
    k0, f = _depth_split(p, s, beta, p.d_count.at(s))
    q = [dr.lerp(dr.gather(jt.Float, c_k, k0), dr.gather(jt.Float, c_k, k0 + 1), f)
         for c_k in cum]
    # added, not written: a second plain scatter to ``out`` (a second
    # channel) would launch the first one's kernel first
    _accumulate(p, out, s, beta, comps, q, active)
    dr.eval(out)


@dr.syntax
def _closed_form_local_kernel(p: _Problem, slices, comps, size, out, add):
    """Per-slice cumulative sums C(k) = Σ_{γ<k} a[γ] in lane-local memory,
    then out = Δγ Σ B lerp(C(k0), C(k0+1), f) for every β of the slice."""
    K = len(comps)
    r_s = p.r_count.at(slices)
    d_s = p.d_count.at(slices)
    cum = dr.alloc_local(jt.Float, size)
    d_s = dr.minimum(d_s, jt.Int(size // K - 1))  # size literal: part of the kernel hash
    run = [jt.Float(0.0) for _ in range(K)]
    g = jt.Int(0)
    for k in range(K):
        cum[k] = jt.Float(0.0)
    while g < d_s:
        a = _leaf(p, slices, g, comps)
        run = [run[k] + a[k] for k in range(K)]
        for k in range(K):
            cum[(g + 1) * K + k] = run[k]
        g += 1
    beta = jt.Int(0)
    while beta < r_s:
        k0, f = _depth_split(p, slices, beta, d_s)
        k1 = dr.minimum(k0 + 1, d_s)
        q = [dr.lerp(cum[k0 * K + k], cum[k1 * K + k], f) for k in range(K)]
        _accumulate(p, out, slices, beta, comps, q, add=add)
        beta += 1


def _run_closed_form(p: _Problem, slices: jt.Int, out: jt.Float):
    if p.lay.nA == 1 and p.L is None:
        return _closed_form_shared(p, slices, out)
    per_leaf = LOCAL_BUDGET // (p.lay.d + 1)
    if per_leaf < 1:
        raise ValueError(f"d = {p.lay.d} light rays do not fit in lane-local memory")
    for chunk, comps in enumerate(_components(p.lay, per_leaf)):
        size = min(_local_size((p.lay.d + 1) * len(comps)), LOCAL_ARRAY_LIMIT)
        _closed_form_local_kernel(p, slices, comps, size, out, chunk > 0)
        dr.eval(out)


# --------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------

def integrate_slices(D, S_modes, A, B, *, L=None, r_count=None, d_count=None,
                     delta_gamma=1.0, skip_unblocked=True) -> jt.TensorXf:
    """Scattered radiance of every view ray of every slice (Eq. 3, Fig. 6).

    Dr.Jit kernels, one lane per slice; semantics, shapes and result as in
    the module docstring and
    :func:`~integrators.tree.partial_sum_reference.integrate_slices_reference`.  With
    ``skip_unblocked`` (default) slices in which no blocker acts take the
    closed form instead of the tree.  Returns a detached ``TensorXf`` of
    shape (n, r) or (n, r, C)."""
    lay = problem_layout(D, S_modes, A, B, L)
    shape = (lay.n, lay.r, lay.C) if lay.coloured else (lay.n, lay.r)
    if lay.n * lay.r * lay.d == 0:
        return dr.zeros(jt.TensorXf, shape)
    p = _prepare(D, S_modes, A, B, L, r_count, d_count)
    out = dr.zeros(jt.Float, lay.n * lay.r * lay.C)
    dr.make_opaque(out)                  # scatter target (see _termination_lists)
    # which slices need the tree: from one host copy of the counts (a
    # compression would read its width back anyway)
    counts = np.asarray(p.updates, np.int64)
    needs_tree = counts > 0 if skip_unblocked else np.ones(lay.n, bool)
    tree_slices = jt.Int(aligned(np.flatnonzero(needs_tree), np.int32))
    free_slices = jt.Int(aligned(np.flatnonzero(~needs_tree), np.int32))
    if dr.width(tree_slices):
        _run_tree(p, tree_slices, counts, out)
    if dr.width(free_slices):
        _run_closed_form(p, free_slices, out)
    return jt.TensorXf(out * jt.Float(delta_gamma), shape)
