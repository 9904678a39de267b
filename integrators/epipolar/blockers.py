"""Blocker maps: where each light ray (and each of its prefiltering
sub-rays) is first blocked coming from the light, traced with Mitsuba or
resampled from a shadow map, converted to the sweep's depth modes
(Baran et al. 2010 §7, Fig. 7; DESIGN §3).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify.coords import light_coords_to_world
from rectify.epipole import EpipolarFrame

from ..core.capture import sample_rng, seed_offset
from ..core.light_transport import first_blocker, point, scalar, vector
from ..core.opaque import Divisor, opaque_scalar
from .light_rays.directional import LightRays
from .queries import EpipolarQueries, frame_memo, row_alpha, searchsorted_rows


def sub_ray_gamma(rays: LightRays, k: int, seed: int, evaluated: bool = False):
    """(row, γ) of ``k`` stratified jittered sub-rays per light ray (§7),
    (n·d·k,) lanes in (row, light ray, sub-ray) order; ``k = 1``: the light
    ray's centre.  A sub-ray's random numbers are keyed by its lane in the
    whole frame (``rays.row_id``), so a subset of the rows draws the full
    render's.  ``evaluated``: evaluated once per light rays, ``k`` and
    ``seed`` (for readers that gather from them: a point light's factor
    and blockers read the same sub-rays)."""
    if not evaluated:
        return _sub_ray_gamma(rays, k, seed)

    def make():
        out = _sub_ray_gamma(rays, k, seed)
        dr.eval(out)
        return out
    return frame_memo(rays, ("sub_ray_gamma", k, seed), make)


def _sub_ray_gamma(rays: LightRays, k: int, seed: int):
    s, g, m = rays.lanes(k)
    if k == 1:
        xi = mi.Float(0.5)
    else:
        n = dr.width(s)
        row_id = getattr(rays, "row_id", None)
        lane = (dr.arange(mi.UInt32, n) if row_id is None else
                (dr.gather(mi.UInt32, row_id, s) * rays.d + g) * k + m)
        rng = sample_rng(lane, seed_offset(seed, 0x2545F4914F6CDD1D))
        xi = (mi.Float(m) + rng.next_float32()) / k
    return s, rays.start(s) + (mi.Float(g) + xi) * dr.gather(mi.Float, rays.delta_gamma, s)


# --------------------------------------------------------------------------
# Blocker maps S[α, γ] (§3, §7)
# --------------------------------------------------------------------------

def _light_top(params, frame: EpipolarFrame) -> float:
    """Axial coordinate u beyond every scene object (rays start there)."""
    bb = params.scene.bbox()
    corners = np.array([[x, y, z] for x in (bb.min[0], bb.max[0])
                        for y in (bb.min[1], bb.max[1]) for z in (bb.min[2], bb.max[2])])
    u = (corners - params.camera.origin) @ frame.axis
    return float(np.max(u)) + 1e-2 * params.scene_extent


#: |second difference| of the blocker indices at neighbouring light-ray
#: boundaries above which an interval traces its §7 sub-rays (in queries;
#: doubled where slice interpolation shares samples between two slices)
EDGE_INDEX_JUMP = 1
#: intervals on either side of a non-smooth boundary that trace their sub-rays too
DILATE = 2
#: rows with more than this fraction of non-smooth intervals trace all sub-rays
DENSE_ROW = 0.15


def _blocker_depth(params, queries: EpipolarQueries, s, gamma):
    """(hit, u_b) of the light rays (row s, γ), traced from above the scene
    along -w_l (:func:`~integrators.core.light_transport.first_blocker`): whether a blocker is
    met and its
    axial coordinate."""
    frame = queries.frame
    U = scalar(_light_top(params, frame))
    origin = light_coords_to_world(frame, row_alpha(queries, s), gamma, U)
    w = vector(frame.axis)
    hit, p = first_blocker(params, origin, -w)
    u_b = dr.dot(mi.Vector3f(p - point(params.camera.origin)), w)
    return hit, u_b


def _blocker_angle(params, queries: EpipolarQueries, s, gamma) -> mi.Float:
    """atan2(γ, u_b) of the light rays (row s, γ) (:func:`_blocker_depth`);
    π where nothing blocks."""
    hit, u_b = _blocker_depth(params, queries, s, gamma)
    return dr.select(hit, dr.atan2(gamma, u_b), math.pi)


def _smooth_intervals(queries: EpipolarQueries, rays: LightRays, hit, e):
    """(smooth_at, e): ``smooth_at(interval, row)``, per lane, whether the
    blockers traced at the d + 1 interval boundaries of light-ray interval
    ``interval`` (of row ``row``) vary smoothly enough around it for a
    linear interpolation of u_b to place every sub-ray in its depth mode.

    A boundary is *calm* when its hit status equals its neighbours' and the
    |second difference| of the boundary blocker indices (in queries) is ≤
    ``EDGE_INDEX_JUMP``: a plane (a floor, a roof, at any light angle: u_b
    linear in γ) is calm, a blocker edge, a thin occluder crossing a
    boundary or a staircase of leaves is not.  An interval is smooth when
    its two boundaries and ``DILATE`` more on either side are calm (thin
    blockers cluster near edges), and its row is not dense with edges
    (> ``DENSE_ROW`` of the row's intervals rough: foliage, where the
    leaves between boundaries are what the sub-rays are for).  Measured at
    640×480: 2-8 % of the intervals traced on the nave and terrain (same
    relMSE as tracing all), 82 % on the grove (relMSE 4.7e-5 → 5.1e-5).
    ``hit``, ``e``: whether the boundary light rays (n·(d + 1) lanes)
    meet a blocker, and its row index (:func:`boundary_index`), evaluated
    with the trace; a boundary's calm is computed where the intervals
    read it (no kernel of its own)."""
    nb = Divisor(rays.d + 1)       # boundaries per row (the frame's: opaque)
    d = opaque_scalar(mi.Int32, rays.d)

    def at(values, tp, s, g, offset):
        return dr.gather(tp, values, s * nb.d + mi.UInt32(dr.clip(g + offset, 0, d)))

    # in samples, not queries: a sample shared by two slices (interpolation)
    # makes up to two queries of a row
    jump = EDGE_INDEX_JUMP * math.ceil(queries.shares - 1e-6)

    def calm(s, g):
        # boundary g of row s (clamped to the row, as a gather of the
        # boundaries' calm would read it), computed where it is read
        g = dr.clip(g, 0, d)
        e_g = at(e, mi.Int32, s, g, 0)
        hit_g = at(hit, mi.Bool, s, g, 0)
        return ((mi.Float(dr.abs(at(e, mi.Int32, s, g, -1) - 2 * e_g + at(e, mi.Int32, s, g, 1)))
                 <= jump)
                & ~(hit_g ^ at(hit, mi.Bool, s, g, -1)) & ~(hit_g ^ at(hit, mi.Bool, s, g, 1)))

    s, g, _ = rays.lanes()
    smooth = mi.Bool(True)
    for offset in range(-DILATE, DILATE + 2):
        smooth &= calm(s, mi.Int32(g) + offset)
    rough = dr.zeros(mi.UInt32, dr.width(rays.delta_gamma))
    dr.scatter_reduce(dr.ReduceOp.Add, rough, dr.select(smooth, mi.UInt32(0), mi.UInt32(1)), s)
    dr.eval(smooth, rough)
    limit = scalar(DENSE_ROW * rays.d)

    def smooth_at(interval, row):
        # a row dense with edges, read where it is asked (no kernel of its own)
        dense = mi.Float(dr.gather(mi.UInt32, rough, row)) > limit
        return dr.gather(mi.Bool, smooth, interval) & ~dense
    return smooth_at, e


def boundary_index(queries: EpipolarQueries, s_b, gamma_b, hit, u_b) -> mi.Int32:
    """The row index (:func:`~integrators.epipolar.queries.searchsorted_rows`)
    of the blocker angle of the boundary light rays (row ``s_b``, γ
    ``gamma_b``) traced as ``(hit, u_b)``."""
    return mi.Int32(searchsorted_rows(queries, s_b, dr.select(hit, dr.atan2(gamma_b, u_b),
                                                               math.pi)))


class SubRayBlockers(NamedTuple):
    """Blocker angles of the sub-rays (n·d·k lanes) and, where known, the
    range [lo, hi] their row index (:func:`~integrators.epipolar.queries.searchsorted_rows`)
    lies in."""
    angle: mi.Float
    lo: mi.UInt32 | None = None
    hi: mi.UInt32 | None = None
    #: the row index itself where it was found with the angles (None: not yet)
    index: mi.UInt32 | None = None


def trace_blocker_angles(params, queries: EpipolarQueries, rays: LightRays, k: int = 1,
                         seed: int = 0, adaptive: bool = False) -> mi.Float:
    """S = atan2(γ, u_b) of ``k`` sub-rays per light ray, (n·d·k,) lanes in
    (row, light ray, sub-ray) order; π where nothing blocks the sub-ray
    (:func:`trace_sub_ray_blockers` without the index bounds)."""
    return trace_sub_ray_blockers(params, queries, rays, k, seed, adaptive).angle


def adaptive_sub_ray_gamma(rays: LightRays, k: int, seed: int = 0):
    """(row, γ) of the sub-rays of ``trace_sub_ray_blockers(adaptive=True)``:
    :func:`sub_ray_gamma`'s, but sub-ray 0 at the centre of the first
    stratum, where the interval's boundary ray is traced."""
    s, gamma = sub_ray_gamma(rays, k, seed)
    _, g, m = rays.lanes(k)
    first = rays.start(s) + (mi.Float(g) + 0.5 / k) * dr.gather(mi.Float, rays.delta_gamma, s)
    return s, dr.select(m == 0, first, gamma)


def trace_sub_ray_blockers(params, queries: EpipolarQueries, rays: LightRays, k: int = 1,
                           seed: int = 0, adaptive: bool = False) -> SubRayBlockers:
    """S = atan2(γ, u_b) of ``k`` sub-rays per light ray (:func:`trace_blocker_angles`).

    Each sub-ray is traced with Mitsuba from outside the scene along -w_l.
    With ``adaptive`` (§7's sub-rays only where they matter), the d + 1
    boundaries of each row's light-ray intervals are traced first; in the
    intervals where the blockers vary smoothly (:func:`_smooth_intervals`)
    the sub-rays' u_b is interpolated linearly between the two boundaries
    (exact for planar blockers), elsewhere the k sub-rays are traced.  The
    boundaries sit at the centres of the intervals' first strata and serve
    as their sub-ray 0 (so a rough interval traces k − 1 more rays); the
    other sub-rays are jittered in their strata as without ``adaptive``.  Away from
    edges this traces one ray per light ray instead of ``k``; a blocker
    thinner than a light-ray interval that crosses no boundary is missed
    (the sub-rays would have found it with probability < 1).  An
    interpolated sub-ray's point (u, γ) moves on the straight segment
    between the boundaries' blocker points, so its angle -- and its row
    index -- lies between theirs: the result carries those index bounds,
    which make :func:`blocker_modes` nearly free where both are equal."""
    s, gamma = sub_ray_gamma(rays, k, seed)
    if k == 1 or not adaptive:
        out = _blocker_angle(params, queries, s, gamma)
        dr.eval(out)
        return SubRayBlockers(out)
    nb = Divisor(rays.d + 1)       # boundaries per row
    n = dr.width(rays.delta_gamma)
    j = dr.arange(mi.UInt32, n * nb.value)
    s_b, j_b = nb.divmod(j)
    c0 = 0.5 / k          # the boundaries sit at the centres of the first strata
    gamma_b = (rays.start(s_b)
               + (mi.Float(j_b) + c0) * dr.gather(mi.Float, rays.delta_gamma, s_b))
    hit, u_b = _blocker_depth(params, queries, s_b, gamma_b)
    e = boundary_index(queries, s_b, gamma_b, hit, u_b)
    dr.eval(hit, u_b, e)                  # their row indices with the trace, one kernel
    smooth, e = _smooth_intervals(queries, rays, hit, e)
    # every sub-ray interpolated: u_b lerped at its place between the
    # boundaries; sub-ray 0 *is* its interval's boundary (f = 0, exact)
    lane = dr.arange(mi.UInt32, dr.width(s))
    owner, m = lane // k, lane % k                        # its interval (n·d lanes)
    g = Divisor(rays.d).divmod(owner)[1]
    b = s * nb.d + g
    dg = dr.gather(mi.Float, rays.delta_gamma, s)
    gamma = adaptive_sub_ray_gamma(rays, k, seed)[1]
    f = dr.select(m == 0, 0.0, (gamma - rays.start(s)) / dg - mi.Float(g) - c0)
    u = dr.lerp(dr.gather(mi.Float, u_b, b), dr.gather(mi.Float, u_b, b + 1), f)
    out = dr.select(dr.gather(mi.Bool, hit, b), dr.atan2(gamma, u), math.pi)
    e0, e1 = dr.gather(mi.Int32, e, b), dr.gather(mi.Int32, e, b + 1)
    lo, hi = mi.UInt32(dr.minimum(e0, e1)), mi.UInt32(dr.maximum(e0, e1))
    # ... and traced (but sub-ray 0, traced already), with the whole row as
    # index range, where not smooth: the interpolation, the rows and
    # angles of the sub-rays to trace and their mask in one kernel
    rough = ~smooth(owner, s) & (m != 0)
    index = searchsorted_rows(queries, s, out, lo, hi)
    dr.eval(out, lo, hi, index, s, gamma, rough)
    sel = dr.compress(rough)
    if dr.width(sel):
        s_sel = dr.gather(mi.UInt32, s, sel)
        sub = _blocker_angle(params, queries, s_sel, dr.gather(mi.Float, gamma, sel))
        dr.scatter(out, sub, sel)
        dr.scatter(lo, 0, sel)
        dr.scatter(hi, opaque_scalar(mi.UInt32, queries.r), sel)
        dr.scatter(index, searchsorted_rows(queries, s_sel, sub), sel)
    dr.eval(out, lo, hi, index)
    return SubRayBlockers(out, lo, hi, index)


def shadow_map_blocker_angles(params, queries: EpipolarQueries, rays, shadow_map, light,
                              k: int = 1, seed: int = 0) -> mi.Float:
    """Like :func:`trace_blocker_angles`, but each sub-ray's blocker read from
    a classic :class:`~integrators.core.capture.ShadowMap` (nearest texel, the
    paper's "rectify the shadow map", §3), for either light kind: a light ray
    of either kind is one of the map's own rays (parallel to an orthographic
    map's, through a perspective or cube map's centre), so it meets one
    texel.  ``light`` (the light model) names the maps it reads
    (``shadow_maps``), where a light ray meets its map (``map_point``) and
    the eye's angle of the blocker at the texel's depth
    (``map_blocker_beta``); π where the map records no blocker."""
    if shadow_map.kind not in light.shadow_maps:
        raise ValueError(f"a {params.light.kind} light needs a shadow map of kind "
                         f"{' or '.join(light.shadow_maps)}, not {shadow_map.kind!r}")
    frame = queries.frame
    s, gamma = sub_ray_gamma(rays, k, seed)
    alpha = row_alpha(queries, s)
    z_b = shadow_map.nearest_depth(light.map_point(frame, alpha, gamma))
    beta_b = dr.select(dr.isfinite(z_b),
                       light.map_blocker_beta(params, frame, shadow_map, alpha, gamma, z_b),
                       math.pi)
    dr.eval(beta_b)
    return beta_b


def axial_map_point(frame: EpipolarFrame, alpha, gamma) -> mi.Point3f:
    """Directional light: the point u = 0 of light ray (α, γ)."""
    return light_coords_to_world(frame, alpha, gamma, 0.0)


def axial_blocker_beta(params, frame: EpipolarFrame, shadow_map, alpha, gamma, z_b) -> mi.Float:
    """Directional light: β_b = atan2(γ, u_b) of the blocker at depth z_b of
    an orthographic map.  A point x at depth z = s0 − x·w is shadowed iff
    z > z_b + bias ⟺ u < s0 − o·w − z_b − bias (o: the eye)."""
    w = np.asarray(shadow_map.frames[0][2], np.float64)
    top = shadow_map.s0 - float(params.camera.origin @ w) - shadow_map.bias
    return dr.atan2(gamma, top - z_b)


def merge_modes(index: mi.UInt32, k: int):
    """(β index, weight) of the k sub-rays of each light ray, equal indices
    merged into one mode of weight count/k (§7, Fig. 7); merged-away slots
    get weight 0 (no update).  One lane per sub-ray slot, compared with the
    k slots of its light ray."""
    j = dr.arange(mi.UInt32, dr.width(index))
    m, base = j % k, j - j % k
    own = mi.Float(index)
    first, same = mi.Bool(True), mi.Float(0.0)
    for i in range(k):
        v = dr.gather(mi.UInt32, index, base + i)
        equal = v == index
        first &= ~(equal & (i < m))
        same += dr.select(equal, 1.0, 0.0)
    return own, dr.select(first, same / k, 0.0)


def blocker_modes(queries: EpipolarQueries, rays: LightRays, beta_b, k: int) -> BlockerModes:
    """Blocker angles of k sub-rays per light ray (a Float, or
    :class:`SubRayBlockers` with index bounds) -> depth modes in the
    sweep's index units (:mod:`integrators.epipolar`, "Blocker map"), (n, d, k) tensors."""
    s, _, _ = rays.lanes(k)
    if not isinstance(beta_b, SubRayBlockers):
        beta_b = SubRayBlockers(beta_b)
    index = beta_b.index
    if index is None:
        index = searchsorted_rows(queries, s, beta_b.angle, beta_b.lo, beta_b.hi)
    b, w = merge_modes(index, k)
    shape = (queries.n, rays.d, k)
    modes = BlockerModes(mi.TensorXf(b, shape=shape), mi.TensorXf(w, shape=shape))
    dr.eval(modes.beta, modes.weight)
    return modes


def leaf_visibility(queries: EpipolarQueries, modes: BlockerModes, leaf=0) -> mi.Float:
    """V(γ ∈ leaf, β_q) per query from the blocker modes, with the sweep's
    semantics (:mod:`~integrators.tree.partial_sum_tree`: a mode at index m
    removes its weight from the row's queries m, m+1, ...); ``leaf``: one
    light-ray index for all queries, or one per query."""
    return mode_visibility(modes, queries.row, queries.col, leaf)


def mode_visibility(modes: BlockerModes, row, col, leaf) -> mi.Float:
    """:func:`leaf_visibility` of arbitrary (row, view-ray index ``col``,
    leaf) lanes."""
    k = modes.beta.shape[2]
    d = modes.beta.shape[1]
    beta, weight = mi.Float(modes.beta.array), mi.Float(modes.weight.array)
    base = (row * d + mi.UInt32(leaf)) * k
    col = mi.Float(col)
    V = mi.Float(1.0)
    for m in range(k):
        acts = dr.gather(mi.Float, beta, base + m) <= col
        V -= dr.select(acts, dr.gather(mi.Float, weight, base + m), 0.0)
    return V


# --------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------

class BlockerModes(NamedTuple):
    """Depth-prefiltered blockers (§7, Fig. 7): ``beta`` and ``weight`` are
    (n, d, M) arrays; mode m of light ray γ of slice s removes the fraction
    ``weight[s, γ, m]`` of the leaf from view ray ⌈``beta[s, γ, m]``⌉ on.
    Unused mode slots have weight 0."""

    beta: object
    weight: object

    @staticmethod
    def from_flat(n_slices, d, slice, gamma, beta, weight) -> "BlockerModes":
        """Dense modes from flat per-update lists (NumPy), in input order.

        M is the largest number of entries of one (slice, γ)."""
        slice = np.asarray(slice, np.int64).ravel()
        gamma = np.asarray(gamma, np.int64).ravel()
        key = slice * d + gamma
        order = np.argsort(key, kind="stable")
        key_sorted = key[order]
        first = np.searchsorted(key_sorted, key_sorted, side="left")
        slot = np.empty_like(key)
        slot[order] = np.arange(key.size) - first
        M = int(slot.max()) + 1 if key.size else 1
        B = np.full((n_slices * d, M), np.inf, np.float32)
        W = np.zeros((n_slices * d, M), np.float32)
        B[key, slot] = np.asarray(beta, np.float32).ravel()
        W[key, slot] = np.asarray(weight, np.float32).ravel()
        return BlockerModes(B.reshape(n_slices, d, M), W.reshape(n_slices, d, M))
