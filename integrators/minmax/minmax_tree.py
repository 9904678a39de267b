"""1-D min/max binary trees per slice and their traversal (Yusov 2013, "1D
min/max binary trees"; Chen et al. 2011).

Tree: level 0 holds each texel's (min, max) blocker depth (:mod:`.light_rays`);
node ``j`` of level ``l`` covers texels ``[j·2^l, (j+1)·2^l)`` and holds the
min of its children's mins and the max of their maxima, and the *colour
state* of its texels' light colours: ``UNIFORM`` (one colour, not black, to
``COLOUR_TOLERANCE``), ``BLACK`` (all black) or ``MIXED``.  A node taken
whole needs no more than that: a lit uniform node adds the colour of its
first texel (level 0 keeps every texel's colour).  Levels ``0 … max_level``
are stored per slice, level ``l`` at offset ``2n − 2n/2^l`` of the slice's
``2n`` entries.  A light of one colour everywhere (directional; a point
light inside the medium) stores no states and no colours at all
(``MinMaxTree.constant_colour``).

Semantics (what the tree must reproduce exactly): the *per-texel march* of a
view ray.  Texel ``i`` owns the part of the ray whose light-ray coordinate
``γ`` lies in its cell ``[γ_lo + iΔ, γ_lo + (i+1)Δ)``; that section is lit
if the ray's point on the texel's light ray ``γ_i`` (clamped to the ray's
ends) lies no deeper than the blocker, ``z ≤ z_b + bias``, and then adds
``colour_i · I(section)`` (:mod:`.section_integral`).

Traversal (talk, "Traversal optimization"): at texel ``i`` and level ``l``
the node's sections are lit if the ray's largest depth at the node's first
and last texel points is ≤ the node's min (and the node's colour state is
``UNIFORM``), shadowed if the ray's smallest depth over them is > the node's
max (or its state is ``BLACK``); then the whole node is one section and the march
moves past it and climbs one level if the new position is aligned to the
next level; otherwise it descends.  Depth along a ray, as a function of the
texel, is monotone (directional) or convex with its minimum at the ray's
closest point to the light (point/spot), so the two end points bound it
(plus that minimum): a node taken whole has every texel test agreeing, and
the tree's sections are unions of the per-texel ones.  ``max_level = 0`` is
the per-texel march itself (the talk's brute force along the slice).

Lit runs: a node lit by its depth test but of ``MIXED`` colour
(a spot's fall-off rim, the edges of a projected texture's panes) has every
texel lit, only their colours differ.  The march remembers that (``run_end``,
the node's end) and descends; inside the run no depth test can fail, and it
does not climb back into a ``MIXED`` node (that would be split again), nor
descend through one: it drops straight to the highest node starting at the
same texel that is not ``MIXED`` (``MinMaxTree.drop``, else the leaf).  The
rim then costs one step per texel instead of about 1.5, and uniform
sub-nodes are still taken whole.

Resampled blockers store conservative (min, max) per texel and their leaves
are not decisive: a leaf then reads the shadow map's PCF visibility at its
point (``leaf_visibility``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify import EpipolarFrame, ray_meeting_t, view_to_light

from ..core.opaque import colour as opaque_colour
from ..core.opaque import floats, scalar
from .light_rays import SliceLightRays


#: a node's colour counts as uniform when its min and max agree to this
#: relative tolerance (float32 rounding of Mitsuba's intensity / r² at r = 1)
COLOUR_TOLERANCE = 1e-5


#: colour states of a node (module docstring)
UNIFORM, BLACK, MIXED = 0, 1, 2


@dataclass(frozen=True, eq=False)
class MinMaxTree:
    """Levels ``0 … levels-1`` of every slice (module docstring).  ``state``
    is None and ``constant_colour`` the light's colour when it is the same
    for every texel."""
    n: int
    levels: int
    z_min: mi.Float = field(repr=False)
    z_max: mi.Float = field(repr=False)
    state: mi.UInt32 | None = field(repr=False, default=None)
    constant_colour: tuple | None = None
    #: per node (with ``state``): the highest level ``≤`` its own at which the
    #: node starting at its first texel is not ``MIXED`` (0: none), where a
    #: descent inside a lit run stops (module docstring)
    drop: mi.UInt32 | None = field(repr=False, default=None)
    slices: int = 0

    @staticmethod
    def offset(n: int, level: int) -> int:
        return 2 * n - (2 * n >> level)


def colour_state(c_lo, c_hi):
    """UNIFORM / BLACK / MIXED of nodes whose texel colours lie in [c_lo, c_hi]."""
    black = dr.all(c_hi <= 0.0)
    uniform = dr.all(c_hi - c_lo <= COLOUR_TOLERANCE * c_hi)
    return dr.select(black, mi.UInt32(BLACK), dr.select(uniform, mi.UInt32(UNIFORM),
                                                        mi.UInt32(MIXED)))


def colour_bounds(colour: mi.Color3f, n: int):
    """(lo, hi): the smallest and largest texel colour of every slice
    (``n`` texels each), per channel: what :func:`constant_colour` decides
    from, slice by slice (a partial render keeps the other slices')."""
    return (mi.Color3f(*(dr.block_reduce(dr.ReduceOp.Min, colour[c], n) for c in range(3))),
            mi.Color3f(*(dr.block_reduce(dr.ReduceOp.Max, colour[c], n) for c in range(3))))


def constant_colour(colour: mi.Color3f, hi: mi.Color3f | None = None):
    """The light's colour if every texel has it (to ``COLOUR_TOLERANCE``) and
    it is finite and not black, else None (overflowed texels then stay
    ``MIXED`` and add nothing, as in the per-texel test).  ``colour``: every
    texel's, or with ``hi`` the lower bounds of groups of texels whose upper
    bounds ``hi`` are (:func:`colour_bounds`: the same answer)."""
    hi = colour if hi is None else hi
    lo = [float(dr.min(colour[c])[0]) for c in range(3)]
    hi = [float(dr.max(hi[c])[0]) for c in range(3)]
    if max(hi) > 0 and all(map(math.isfinite, hi)) \
            and all(h - l <= COLOUR_TOLERANCE * h for l, h in zip(lo, hi)) \
            and all(l > 0 or h <= 0 for l, h in zip(lo, hi)):
        return tuple(0.5 * (l + h) for l, h in zip(lo, hi))
    return None


#: ``build_tree``'s ``const`` default: the constant colour of ``rays`` themselves
OWN_COLOUR = "own"


#: levels one kernel of :func:`build_tree` adds: each node reduces up to
#: ``2^BLOCK_LEVELS`` nodes of the level the block starts from
BLOCK_LEVELS = 6


def build_tree(rays: SliceLightRays, max_level: int | None = None,
               const=OWN_COLOUR) -> MinMaxTree:
    """Build levels up to ``max_level`` (default: the root, log2 n).  Levels
    are built in blocks of :data:`BLOCK_LEVELS`, each block one kernel: a
    node of the block reduces the nodes below it of the level the block
    starts from (the leaves, or the last block's top level, whose colour
    bounds live only until the next block), in order, so the running
    bounds after ``2^m`` of them are those of the node of level ``m``
    starting at its first texel, whose colour state sets ``drop``.
    ``const``: the frame's constant light colour (:func:`constant_colour`
    of every slice's texels, None: not constant) when ``rays`` are some of
    its slices."""
    n, S = rays.n, rays.slices
    top = int(math.log2(n))
    max_level = top if max_level is None else max(0, min(int(max_level), top))
    if isinstance(const, str) and const == OWN_COLOUR:
        const = constant_colour(rays.colour)
    size = S * 2 * n
    tree = dict(z_min=dr.full(mi.Float, dr.inf, size), z_max=dr.full(mi.Float, -dr.inf, size))
    if const is None:
        tree.update(state=dr.full(mi.UInt32, MIXED, size), drop=dr.zeros(mi.UInt32, size))
    idx = dr.arange(mi.UInt32, S * n)
    k = idx // n
    dst = k * (2 * n) + (idx - k * n)
    dr.scatter(tree["z_min"], rays.z_min, dst)
    dr.scatter(tree["z_max"], rays.z_max, dst)
    if const is None:
        dr.scatter(tree["state"], colour_state(rays.colour, rays.colour), dst)
    # the level a block starts from: compact (stride n >> l0 per slice) or in the tree
    src = _Source(level=0, stride=n, base=0, z_min=rays.z_min, z_max=rays.z_max,
                  c_lo=rays.colour, c_hi=rays.colour, drop=None)
    while src.level < max_level:
        src = _build_block(tree, src, n, S, min(src.level + BLOCK_LEVELS, max_level))
    dr.eval(*tree.values())
    return MinMaxTree(n=n, levels=max_level + 1, constant_colour=const, slices=S, **tree)


@dataclass(frozen=True, eq=False)
class _Source:
    level: int
    stride: int               # of the depths and drops: per slice, and the level's offset
    base: int
    z_min: mi.Float
    z_max: mi.Float
    c_lo: mi.Color3f
    c_hi: mi.Color3f
    drop: mi.UInt32 | None


def _build_block(tree: dict, src: _Source, n: int, S: int, l1: int) -> _Source:
    """Levels ``src.level + 1 … l1`` of every slice, one lane per node
    (:func:`build_tree`); returns level ``l1`` as the next block's source."""
    l0 = src.level
    colours = "state" in tree
    first_t = MinMaxTree.offset(n, l0 + 1)
    T = MinMaxTree.offset(n, l1 + 1) - first_t   # nodes of the block per slice
    idx = dr.arange(mi.UInt32, S * T)
    k = idx // T
    t = idx - k * T + first_t                    # the node's place in its slice's 2n entries
    level = mi.UInt32(l0 + 1)
    for l in range(l0 + 2, l1 + 1):
        level = dr.select(t >= MinMaxTree.offset(n, l), mi.UInt32(l), level)
    j = t - (2 * n - (mi.UInt32(2 * n) >> level))
    shift = level - l0
    count = mi.UInt32(1) << shift
    first = j << shift
    start = k * src.stride + src.base + first
    c_start = k * (n >> l0) + first              # the colour bounds are compact
    drop0 = dr.zeros(mi.UInt32, S * T) if src.drop is None else \
        dr.gather(mi.UInt32, src.drop, start)

    def body(i, lo, hi, c_lo, c_hi, d, m):
        at = start + i
        lo = dr.minimum(lo, dr.gather(mi.Float, src.z_min, at))
        hi = dr.maximum(hi, dr.gather(mi.Float, src.z_max, at))
        i = i + 1
        if colours:
            c_lo = dr.minimum(c_lo, dr.gather(mi.Color3f, src.c_lo, c_start + i - 1))
            c_hi = dr.maximum(c_hi, dr.gather(mi.Color3f, src.c_hi, c_start + i - 1))
            # 2^m' nodes reduced: the bounds of the node of level l0 + m' at the first texel
            whole = i == (mi.UInt32(1) << m)
            d = dr.select(whole & (colour_state(c_lo, c_hi) != MIXED), l0 + m, d)
            m = dr.select(whole, m + 1, m)
        return i, lo, hi, c_lo, c_hi, d, m

    inf = dr.full(mi.Float, dr.inf, S * T)
    c0 = dr.full(mi.Color3f, dr.inf, S * T) if colours else mi.Color3f(0.0)
    c1 = dr.full(mi.Color3f, -dr.inf, S * T) if colours else mi.Color3f(0.0)
    _, lo, hi, c_lo, c_hi, d, _ = dr.while_loop(
        state=(dr.zeros(mi.UInt32, S * T), inf, -inf, c0, c1, drop0, dr.full(mi.UInt32, 1, S * T)),
        cond=lambda i, *_: i < count, body=body)
    dst = k * (2 * n) + t
    dr.scatter(tree["z_min"], lo, dst)
    dr.scatter(tree["z_max"], hi, dst)
    m = n >> l1
    out_c_lo = out_c_hi = c_lo
    if colours:
        dr.scatter(tree["state"], colour_state(c_lo, c_hi), dst)
        dr.scatter(tree["drop"], d, dst)
        # the top level's colour bounds, compact, for the next block
        out_c_lo, out_c_hi = dr.zeros(mi.Color3f, S * m), dr.zeros(mi.Color3f, S * m)
        top = level == l1
        dr.scatter(out_c_lo, c_lo, k * m + j, top)
        dr.scatter(out_c_hi, c_hi, k * m + j, top)
    dr.eval(*tree.values(), out_c_lo, out_c_hi) if colours else dr.eval(*tree.values())
    return _Source(level=l1, stride=2 * n, base=MinMaxTree.offset(n, l1), z_min=tree["z_min"],
                   z_max=tree["z_max"], c_lo=out_c_lo, c_hi=out_c_hi,
                   drop=tree.get("drop"))


def build_tree_reference(z_min, z_max, colour, max_level=None):
    """NumPy twin: list of per-level ``(z_min, z_max, c_min, c_max)`` arrays
    of shape (S, n >> l[, 3])."""
    z_min, z_max, colour = (np.asarray(a, dtype=np.float64) for a in (z_min, z_max, colour))
    n = z_min.shape[1]
    top = int(math.log2(n)) if max_level is None else int(max_level)
    out = [(z_min, z_max, colour, colour)]
    for _ in range(top):
        a, b, c, d = out[-1]
        out.append((np.minimum(a[:, ::2], a[:, 1::2]), np.maximum(b[:, ::2], b[:, 1::2]),
                    np.minimum(c[:, ::2], c[:, 1::2]), np.maximum(d[:, ::2], d[:, 1::2])))
    return out


def drop_reference(states):
    """NumPy twin of ``MinMaxTree.drop`` from the per-level colour states
    (list of (S, n >> l) arrays, level 0 first), by a scan down each node's
    first texels."""
    out = []
    for level, st in enumerate(states):
        d = np.zeros(st.shape, dtype=np.int64)
        for k, j in np.ndindex(*st.shape):
            first = j << level
            d[k, j] = next((m for m in range(level, 0, -1)
                            if states[m][k, first >> m] != MIXED), 0)
        out.append(d)
    return out


def colour_state_reference(c_min, c_max):
    """NumPy twin of :func:`colour_state` on (..., 3) bounds."""
    black = np.all(c_max <= 0, axis=-1)
    uniform = np.all(c_max - c_min <= COLOUR_TOLERANCE * c_max, axis=-1)
    return np.where(black, BLACK, np.where(uniform, UNIFORM, MIXED))


# --------------------------------------------------------------------------
# ray geometry in its slice
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SliceRays:
    """The view rays to march, one per lane: slice ``k``, angle ``β`` from
    the camera–light axis, pinhole→origin distance ``t_near`` and the range
    ``[0, t_end]`` (from the ray origin) to integrate."""
    k: mi.UInt32
    beta: mi.Float
    t_near: mi.Float
    t_end: mi.Float
    alpha: mi.Float


def depth_at(frame: EpipolarFrame, rays: SliceRays, u_top: mi.Float, t):
    """Depth from the light's depth origin of the point ``t`` of each ray."""
    _, u = view_to_light(frame, rays.alpha, rays.beta, rays.t_near + t)
    return (u_top - u) if frame.is_directional else u


def depth_range(frame: EpipolarFrame, rays: SliceRays, u_top: mi.Float, t_a, t_b):
    """(min, max) depth over the ray points ``t ∈ [t_a, t_b]`` (monotone for
    directional light; point/spot: convex, minimum ``h`` at the closest point)."""
    z_a, z_b = depth_at(frame, rays, u_top, t_a), depth_at(frame, rays, u_top, t_b)
    lo, hi = dr.minimum(z_a, z_b), dr.maximum(z_a, z_b)
    if not frame.is_directional:
        D = scalar(frame.light_distance)
        sb, cb = dr.sincos(rays.beta)
        t_c = D * cb - rays.t_near
        lo = dr.select((t_c > t_a) & (t_c < t_b), D * sb, lo)
    return lo, hi


def t_at_gamma(frame: EpipolarFrame, rays: SliceRays, gamma, t_lo, t_hi):
    """Ray parameter (from the origin) where the ray meets light ray ``γ``,
    clamped to ``[t_lo, t_hi]`` (never met: ``t_hi``)."""
    t, ok = ray_meeting_t(frame, rays.beta, gamma)
    t = dr.select(ok, t - rays.t_near, dr.inf)
    return dr.clip(t, t_lo, t_hi)


# --------------------------------------------------------------------------
# traversal
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class MarchResult:
    L: mi.Color3f = field(repr=False)       # Σ colour · V · I over the sections
    steps: mi.UInt32 = field(repr=False)    # loop iterations per ray
    tally: dict | None = field(repr=False, default=None)   # steps per kind (``STEP_KINDS``)


#: what a step of the march met (``march_tree(tally=True)``): a node taken
#: whole lit / shadowed above level 0 or at a leaf, shadowed by its colour
#: state (``BLACK``), split because its colour is ``MIXED`` though its depth
#: test says lit, or split because the ray's depth straddles the node's
#: blocker range (a genuine shadow boundary; at a leaf: resampled blockers)
STEP_KINDS = ("lit_node", "lit_leaf", "dark_node", "dark_leaf", "black", "colour_split",
              "boundary_split", "boundary_leaf")


def step_kind(lit_depth, dark_depth, state, leaf):
    """Index into ``STEP_KINDS`` of each lane's step."""
    black = ~dark_depth & (state == BLACK)
    mixed = state == MIXED
    k = dr.select(leaf, mi.UInt32(7), mi.UInt32(6))                     # boundary
    k = dr.select(lit_depth & mixed & ~leaf, mi.UInt32(5), k)
    k = dr.select(lit_depth & ~mixed, dr.select(leaf, mi.UInt32(1), mi.UInt32(0)), k)
    k = dr.select(lit_depth & mixed & leaf, mi.UInt32(1), k)
    k = dr.select(dark_depth, dr.select(leaf, mi.UInt32(3), mi.UInt32(2)), k)
    return dr.select(black, mi.UInt32(4), k)


def coloured(I, colour):
    """A section's unit-colour integral ``I`` times the light's ``colour``;
    an integral that underflowed to 0 stays 0 (the colour's capped
    light-side factor may overflow: inf·0)."""
    return dr.select(I > 0, I * colour, 0.0)


def march_tree(frame: EpipolarFrame, light_rays: SliceLightRays, tree: MinMaxTree,
               rays: SliceRays, section, max_level: int | None = None,
               leaf_visibility=None, tally: bool = False,
               end_visibility=None) -> MarchResult:
    """March every ray through its slice's tree (module docstring).

    ``section(t_a, t_b)`` → Color3f is the unit-colour in-scattering of a ray
    section (:mod:`.section_integral`; it may close over per-ray values).
    ``leaf_visibility(t)`` → Float in [0, 1] (resampled blockers) replaces the
    leaf's own test.  ``max_level`` caps the levels used (0: per texel).
    ``end_visibility(t)`` → (Float in [0, 1], Color3f) (traced blockers):
    the exact visibility of the ray's point ``t`` and the light's colour
    along its own light ray (as :func:`~.light_rays.texel_colour`); given,
    the *end texels* of a ray
    whose test point is clamped to the ray's end (its light ray ``γ_i``
    lies beyond the ray's γ range: the ray starts or stops inside the
    texel's cell, on an occluder's face say) take their section's visibility
    from it at the section's midpoint instead of comparing the ray's end
    with the blocker along ``γ_i`` -- a blocker ``Δγ`` away, which near a
    light next to a wall (a light inside a closed box) lights the section
    in front of the wall's dark side.
    ``tally``: also count the steps of each kind (``STEP_KINDS``, a diagnosis
    of where the steps go; the march itself is unchanged)."""
    n = light_rays.n
    top = tree.levels - 1 if max_level is None else max(0, min(int(max_level), tree.levels - 1))
    lo_k = dr.gather(mi.Float, floats(light_rays.gamma_lo), rays.k)
    dg = dr.gather(mi.Float, floats(light_rays.delta), rays.k)
    hi_k = lo_k + n * dg
    u_top, bias = scalar(light_rays.u_top), scalar(light_rays.bias)
    zero = dr.zeros(mi.Float, dr.width(rays.t_end))
    g_s, _ = view_to_light(frame, rays.alpha, rays.beta, rays.t_near)
    g_e, _ = view_to_light(frame, rays.alpha, rays.beta, rays.t_near + rays.t_end)
    # clip the ray to the texels' γ range (spot cone)
    t_lo = dr.select(g_s < lo_k, t_at_gamma(frame, rays, lo_k, zero, rays.t_end), zero)
    t_hi = dr.select(g_e > hi_k, t_at_gamma(frame, rays, hi_k, zero, rays.t_end), rays.t_end)
    g_s, g_e = dr.clip(g_s, lo_k, hi_k), dr.clip(g_e, lo_k, hi_k)
    inv = dr.rcp(dg)
    i_first = mi.UInt32(dr.clip(dr.floor((g_s - lo_k) * inv), 0, n - 1))
    i_last = mi.UInt32(dr.clip(dr.floor((g_e - lo_k) * inv), 0, n - 1))
    active = (t_hi > t_lo) & (g_e > g_s - 1e-30)
    base = rays.k * (2 * n)

    def t_edge(e):
        """t of texel edge e (clamped to the ray)."""
        t = t_at_gamma(frame, rays, lo_k + mi.Float(e) * dg, t_lo, t_hi)
        t = dr.select(e <= i_first, t_lo, t)
        return dr.select(e > i_last, t_hi, t)

    def t_test(i):
        return t_at_gamma(frame, rays, lo_k + (mi.Float(i) + 0.5) * dg, t_lo, t_hi)

    def start_level(i):
        return dr.minimum(dr.tzcnt(i), top)

    def climb(i, level, run_end):
        """One level up if ``i`` starts a node of the next level (talk: the
        march's level follows the local scale of the height map), unless
        that node lies in the lit run (``i < run_end``) and its colour is
        ``MIXED``: it would only be split again."""
        up = (level < top) & (((i >> level) & 1) == 0)
        if tree.state is not None:
            parent = base + (2 * n - ((2 * n) >> (level + 1))) + (i >> (level + 1))
            mixed = dr.gather(mi.UInt32, tree.state, parent, up & (i < run_end)) == MIXED
            up &= ~(mixed & (i < run_end))
        return dr.select(up, level + 1, level)

    def body(i, level, L, steps, run_end, *counts):
        size = mi.UInt32(1) << level
        end = dr.minimum(i + size, last + 1)                # texels [i, end) of the march
        node = base + (2 * n - ((2 * n) >> level)) + (i >> level)
        z_lo, z_hi = dr.gather(mi.Float, tree.z_min, node), dr.gather(mi.Float, tree.z_max, node)
        r_lo, r_hi = depth_range(frame, rays, u_top, t_test(i), t_test(end - 1))
        in_run = i < run_end                # texels [i, run_end) are known lit (lit run)
        lit = in_run | (r_hi <= z_lo + bias)
        dark = ~in_run & (r_lo > z_hi + bias)
        leaf = level == 0
        st = None if tree.state is None else dr.gather(mi.UInt32, tree.state, node)
        if counts:
            kind = step_kind(lit, dark, mi.UInt32(UNIFORM) if st is None else st, leaf)
            counts = tuple(c + dr.select(kind == j, mi.UInt32(1), mi.UInt32(0))
                           for j, c in enumerate(counts))
        if st is not None:
            # lit by depth but of mixed colour: every texel of the node is
            # lit, only its colours differ; remember so (the lit run) and descend
            run_end = dr.select(lit & (st == MIXED) & ~leaf, dr.maximum(run_end, end), run_end)
            lit &= st == UNIFORM
            dark |= st == BLACK
        V = dr.select(lit, 1.0, 0.0)
        if leaf_visibility is not None:
            undecided = leaf & ~lit & ~dark
            V = dr.select(undecided, leaf_visibility(t_test(i), i), V)
            lit |= undecided & (V > 0)
        done = lit | dark | leaf
        add = done & lit
        ta, tb = t_edge(i), t_edge(end)
        I = V * section(ta, tb)
        if tree.state is not None:       # a uniform node's colour: its first texel's
            I = coloured(I, dr.gather(mi.Color3f, light_rays.colour, rays.k * n + i, add))
        L = dr.select(add, L + I, L)
        i_next = dr.select(done, i + size, i)
        down = level - 1
        if tree.state is not None:
            # inside a lit run the mixed nodes below would only be split:
            # go straight to the first node that is not (``drop``)
            skip = ~done & (i < run_end)
            child = base + (2 * n - ((2 * n) >> down)) + (i >> down)
            down = dr.select(skip, dr.gather(mi.UInt32, tree.drop, child, skip), down)
        level = dr.select(done, climb(i_next, level, run_end), down)
        return (i_next, level, L, steps + 1, run_end, *counts)

    width = dr.width(rays.t_end)
    L0 = dr.zeros(mi.Color3f, width)
    i_start, i_stop = mi.UInt32(i_first), mi.UInt32(i_last)
    if end_visibility is not None:
        # end texels whose test point is clamped to the ray's end: exact
        # visibility at their section's midpoint (docstring); the march
        # covers the texels between them
        half = scalar(0.5)
        head = active & (lo_k + (mi.Float(i_first) + half) * dg < g_s)
        tail = active & (lo_k + (mi.Float(i_last) + half) * dg > g_e)
        single = i_first == i_last          # one texel, clamped at either end
        tail |= single & head
        head &= ~single

        def end_section(on, i, ta, tb):
            on = on & (tb > ta)
            V, c = end_visibility(half * (ta + tb))
            on &= V > 0
            I = section(ta, tb)
            if tree.state is not None:
                I = coloured(I, c)
            return dr.select(on, I, 0.0)

        L0 += end_section(head, i_first, t_lo, t_edge(i_first + 1))
        L0 += end_section(tail, i_last, dr.select(single, t_lo, t_edge(i_last)), t_hi)
        i_start = dr.select(head, i_start + 1, i_start)
        # the march's last texel, as i_last + 1 - tail (no underflow at 0)
        i_stop = dr.select(tail, i_stop, i_stop + 1)
        active &= i_start < i_stop
        i_stop = dr.select(active, i_stop - 1, i_stop)
        last = i_stop
    else:
        last = i_last

    def cond(i, level, L, steps, run_end, *counts):
        return active & (i <= last)

    counts = tuple(dr.zeros(mi.UInt32, width) for _ in STEP_KINDS) if tally else ()
    state = (mi.UInt32(i_start), start_level(i_start), L0,
             dr.zeros(mi.UInt32, width), mi.UInt32(i_start), *counts)
    i, level, L, steps, _, *counts = dr.while_loop(state=state, cond=cond, body=body)
    if tree.constant_colour is not None:
        L = L * opaque_colour(tree.constant_colour)
    return MarchResult(L=L, steps=steps, tally=dict(zip(STEP_KINDS, counts)) if tally else None)


# --------------------------------------------------------------------------
# NumPy oracle: the per-texel march of one ray
# --------------------------------------------------------------------------


def march_texels_reference(frame, z_b, colour, gamma_lo, delta, u_top, bias, beta, t_near, t_end,
                           section, alpha=0.0):
    """Per-texel march of one ray (float64): returns ``(L, lit)`` with ``L``
    = Σ colour_i · section(t_a, t_b) over lit texels and ``lit`` the list of
    lit texel indices.  ``z_b`` (n,), ``colour`` (n, 3)."""
    from rectify import ray_meeting_t_reference, view_to_light_reference
    n = len(z_b)

    def t_of(g):
        t, ok = ray_meeting_t_reference(frame, beta, g)
        t = float(np.asarray(t).reshape(-1)[0]) - t_near if bool(np.asarray(ok).reshape(-1)[0]) \
            else np.inf
        return min(max(t, t_lo), t_hi)

    def depth(t):
        _, u = view_to_light_reference(frame, alpha, beta, t_near + t)
        u = float(np.asarray(u).reshape(-1)[0])
        return (u_top - u) if frame.is_directional else u

    hi = gamma_lo + n * delta
    g_s = float(np.asarray(view_to_light_reference(frame, alpha, beta, t_near)[0]).reshape(-1)[0])
    g_e = float(np.asarray(view_to_light_reference(frame, alpha, beta,
                                                   t_near + t_end)[0]).reshape(-1)[0])
    t_lo, t_hi = 0.0, t_end
    if g_s < gamma_lo:
        t_lo = t_of(gamma_lo)
    if g_e > hi:
        t_hi = t_of(hi)
    g_s, g_e = min(max(g_s, gamma_lo), hi), min(max(g_e, gamma_lo), hi)
    L = np.zeros(3)
    lit = []
    if not t_hi > t_lo:
        return L, lit
    i0 = int(min(max(math.floor((g_s - gamma_lo) / delta), 0), n - 1))
    i1 = int(min(max(math.floor((g_e - gamma_lo) / delta), 0), n - 1))
    for i in range(i0, i1 + 1):
        ta = t_lo if i == i0 else t_of(gamma_lo + i * delta)
        tb = t_hi if i == i1 else t_of(gamma_lo + (i + 1) * delta)
        z = depth(t_of(gamma_lo + (i + 0.5) * delta))
        c = np.asarray(colour[i], dtype=np.float64)
        if z <= z_b[i] + bias and np.any(c > 0):
            lit.append(i)
            L += c * np.asarray(section(ta, tb), dtype=np.float64)
    return L, lit
