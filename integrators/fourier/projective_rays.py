"""Light rays of Klehm et al. 2014's projective rectification (§4.2):
texel columns over the projective map's rows, their blockers and their
separated kernel.

Projective rectification (Klehm §4.2)
-------------------------------------
:class:`~integrators.fourier.projective_rays.ProjectiveLightRays`: the rows of
:func:`~rectify.projective.projective_rows` with texels equally spaced in
1/x (:func:`~rectify.projective.projective_columns`), so texels are
unequally wide.  Coverage uses the fractional texel index of
:meth:`~integrators.fourier.projective_rays.ProjectiveLightRays.query_depth` (the fraction
linear in γ), the
weights carry the integral over each texel (:func:`texel_integral`: Eq. 12
with the map's own edges; :func:`~integrators.fourier.projective_rays.texel_separated_kernel`),
and the
per-query terms (:func:`~integrators.fourier.projective_rays.projective_query_terms`) divide by
sin β only.
NumPy oracles: :func:`~integrators.fourier.projective_rays.query_depth_reference`,
:func:`texel_integral_reference`, :func:`eq12_weights_reference` (Eq. 12
as printed).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify.projective import ProjectiveColumns, ProjectiveRows, auto_splits, projective_columns

from ..core.light_transport import color, segment_weight
from ..core.opaque import Divisor, floats, scalar, scalar_u32
from ..epipolar.kernel.separation import separate_kernel
from ..epipolar.light_rays.directional import LightRays, with_box_exits
from ..epipolar.light_rays.layout import LightRayLayout
from ..epipolar.query_terms import directional_query_terms
from .rectified_map import texel_integral


# --------------------------------------------------------------------------
# Projective rectification (Klehm §4.2): non-uniform texels
# --------------------------------------------------------------------------
#
# Rows are the slices of :class:`~rectify.projective.ProjectiveRows` (equal
# steps in tan(α − α_mid)); texel ``k`` of every row is the light ray at
# ``x ∈ [x_k, x_{k+1})`` along the bisectrix (equal steps in 1/x within each
# of Klehm's splits, :class:`~rectify.projective.ProjectiveColumns`), i.e.
# ``γ ∈ [x_k, x_{k+1}) / cos φ`` on the row.  The texels are not equally wide,
# so each carries its own width: the filter weights and the separated kernel
# hold the exact integral of the kernel over the texel (Eq. 12), and the
# per-query factor is 1/sin β alone.

@dataclass(frozen=True, eq=False)
class ProjectiveLightRays(LightRayLayout):
    """``d`` light rays (texels) per row with the edges of
    :class:`~rectify.projective.ProjectiveColumns` (module section above):
    a light-ray layout (:class:`~integrators.epipolar.light_rays.layout.LightRayLayout`)
    whose texels are not equally wide (``delta_gamma`` is each row's *mean*
    texel width), so it has no ``start``: the stages of equally wide light
    rays (sub-rays, rectified depth) take :meth:`positions`, :meth:`widths`
    and :meth:`query_depth` instead.  ``h``, ``h_ref``: the box exits of a
    directional light (:func:`~integrators.epipolar.light_rays.directional.with_box_exits`)."""
    d: int
    columns: ProjectiveColumns
    inv_cos: mi.Float       # (n,) 1/cos φ of each row: γ = x/cos φ
    x_edges: mi.Float       # (d + 1,)
    x_widths: mi.Float      # (d,) x_{k+1} − x_k (from float64)
    gamma_max: mi.Float     # (n,) last edge of each row
    delta_gamma: mi.Float   # (n,) mean texel width of each row
    h: mi.Float = None      # (n·d,) axial exit h(α, γ) of the light ray through each centre
    h_ref: mi.Float = None  # (n,) smallest finite h of the row

    def positions(self, offset: float = 0.5):
        """(row, γ) of every texel at ``offset`` ∈ [0, 1] across it *in
        column space* (0: its start, 1: its end, 0.5: the light ray through
        the texel's centre, the middle in 1/x), (n·d,) lanes."""
        s, g, _ = self.lanes()
        return s, self.position(s, g, offset)

    def position(self, s, g, offset: float = 0.5) -> mi.Float:
        """γ of texel ``g`` of rows ``s`` at ``offset`` (as :meth:`positions`)."""
        if offset in (0.0, 1.0):
            x = dr.gather(mi.Float, self.x_edges, g + int(offset))
        else:
            a = dr.rcp(dr.gather(mi.Float, self.x_edges, g))
            b = dr.rcp(dr.gather(mi.Float, self.x_edges, g + 1))
            x = dr.rcp(dr.lerp(a, b, offset))
        return dr.gather(mi.Float, self.inv_cos, s) * x

    def widths(self) -> mi.Float:
        """(n·d,) γ-width of every texel."""
        s, g, _ = self.lanes()
        return dr.gather(mi.Float, self.inv_cos, s) * dr.gather(mi.Float, self.x_widths, g)

    def texel_weights(self) -> mi.Float:
        return self.widths()

    def own_kernel(self, sigma_t: float):
        """Eq. 12: a texel's exact integral with the map's own edges (σt a
        kernel parameter)."""
        _, gamma = self.positions(0.0)
        widths = self.widths()
        sigma = scalar(sigma_t)
        return lambda t, tan: texel_integral(dr.gather(mi.Float, gamma, t),
                                             dr.gather(mi.Float, widths, t), sigma * tan)

    def read_blockers(self, read, params, queries, *args, **kw) -> mi.Float:
        """One light ray through each texel's centre (``lit`` is not
        used: a directional light lights every texel)."""
        return texel_blocker_angles(read, params, queries, self, *args)

    def query_depth(self, queries) -> mi.Float:
        """D (Q,): each query's end point as a fractional texel index, the
        fraction linear in γ within the texel (as the uniform rectified
        depth); x_end = γ_end cos φ of the query's row, found by bisection
        in the shared edge table."""
        x = queries.gamma_end / dr.gather(mi.Float, self.inv_cos, queries.row)
        d_o = scalar_u32(self.d)
        k = first_edge_above(self.x_edges, self.d, x)
        k = dr.clip(mi.Int32(k) - 1, 0, mi.Int32(d_o) - 1)
        k = mi.UInt32(k)
        x0 = dr.gather(mi.Float, self.x_edges, k)
        f = (x - x0) / dr.gather(mi.Float, self.x_widths, k)
        return dr.clip(mi.Float(k) + dr.clip(f, 0.0, 1.0), 0.0, mi.Float(d_o))


def first_edge_above(edges: mi.Float, d: int, x: mi.Float) -> mi.UInt32:
    """The first index i ∈ [0, d] with edges[i] > x (d if none), by
    bisection (``dr.binary_search`` with the bounds as kernel parameters:
    d only sets the number of halvings, d.bit_length() + 1, which the
    search stops needing once its interval is empty)."""
    d_o = scalar_u32(d)
    start, end = dr.zeros(mi.UInt32, dr.width(x)), dr.zeros(mi.UInt32, dr.width(x)) + d_o
    for _ in range(int(d).bit_length() + 1):
        middle = (start + end) >> 1
        below = dr.gather(mi.Float, edges, dr.minimum(middle, d_o)) <= x
        start = dr.select(below, dr.minimum(middle + 1, end), start)
        end = dr.select(below, end, middle)
    return start


def query_depth_reference(queries, rays: ProjectiveLightRays) -> np.ndarray:
    """NumPy oracle of :meth:`ProjectiveLightRays.query_depth` (float64)."""
    edges = rays.columns.edges
    x = np.asarray(queries.gamma_end, np.float64) / np.asarray(rays.inv_cos,
                                                               np.float64)[np.asarray(queries.row)]
    k = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    f = np.clip((x - edges[k]) / (edges[k + 1] - edges[k]), 0.0, 1.0)
    return np.clip(k + f, 0.0, len(edges) - 1)


def projective_x_range(queries, rows: ProjectiveRows, far_margin: float = 1e-5,
                       min_ratio: float = 1e-5):
    """(x_lo, x_hi): the range of x = γ cos φ the queries' camera rays span
    on their rows, from the start on the near plane (t_near) to the end;
    the map is fitted to it (Klehm fits it to the frustum corners).  x_lo is
    at least ``min_ratio`` x_hi (a camera without near plane)."""
    inv_cos = floats(rows.inv_cos[np.asarray(queries.slice_index)])
    c = dr.gather(mi.Float, inv_cos, queries.row)
    x_start = queries.t_near * dr.sin(queries.beta) / c
    x_end = queries.gamma_end / c
    x_hi = float(dr.max(x_end)[0]) * (1.0 + far_margin)
    x_lo = float(dr.min(x_start)[0]) * (1.0 - far_margin)
    return max(x_lo, min_ratio * x_hi), x_hi


def projective_light_rays(params, queries, rows: ProjectiveRows,
                          columns: ProjectiveColumns) -> ProjectiveLightRays:
    """The texels of every row (their γ) and where the light ray through
    each texel centre leaves the medium box toward the light (h; +inf if it
    misses the box), as :func:`~integrators.epipolar.light_rays.directional.light_ray_grid`."""
    inv_cos64 = rows.inv_cos[np.asarray(queries.slice_index)]
    inv_cos = floats(inv_cos64)
    e = columns.edges
    rays = ProjectiveLightRays(
        d=columns.d, columns=columns, inv_cos=inv_cos,
        x_edges=floats(e),
        x_widths=floats(np.diff(e)),
        gamma_max=floats(inv_cos64 * e[-1]),
        delta_gamma=floats(inv_cos64 * (e[-1] - e[0]) / columns.d))
    return with_box_exits(params, queries, rays)


def texel_blocker_angles(read, params, queries, rays: ProjectiveLightRays, *args) -> mi.Float:
    """β_b (n·d) of the light ray through every texel centre, by a blocker
    reader of equal-width light rays (the directional light model's
    ``trace_blockers`` or ``resample_blockers``, called with ``*args``
    after the rays): every texel is handed to it as
    a row of its own with one light ray centred on the texel's."""
    s, gamma = rays.positions(0.5)
    w = rays.widths()
    single = LightRays(1, gamma + 0.5 * w, w, None, None, gamma_lo=gamma - 0.5 * w)
    per_texel = replace(queries, n=queries.n * rays.d,
                        alpha=dr.gather(mi.Float, queries.alpha, s))
    return read(params, per_texel, single, *args)


#: Gauss–Legendre nodes and weights on [0, 1] (2 points: exact to degree 3;
#: for e^{-c γ} over a texel of width w the relative error is (c w)^4/4320,
#: below 1e-5 for c w < 0.4 -- a texel across which the kernel decays by a
#: third; the automatic texel counts keep c w far below that)
GAUSS_NODES = (0.5 - 0.5 / math.sqrt(3.0), 0.5 + 0.5 / math.sqrt(3.0))
GAUSS_WEIGHTS = (0.5, 0.5)


def gauss_nodes(rays: ProjectiveLightRays):
    """(count, γ) of the Gauss nodes of every texel, (n·d·len(GAUSS_NODES),)
    lanes in (row, texel, node) order: where the texel integrals of the
    separated kernel are evaluated."""
    s, lo = rays.positions(0.0)
    w = rays.widths()
    n_g = len(GAUSS_NODES)
    j = dr.arange(mi.UInt32, dr.width(lo) * n_g)
    texel, node = j // n_g, j % n_g
    node_x = dr.gather(mi.Float, floats(GAUSS_NODES), node)
    return dr.width(j), dr.gather(mi.Float, lo, texel) + node_x * dr.gather(mi.Float, w, texel)


def texel_separated_kernel(model, params, queries, rays: ProjectiveLightRays, rank: int,
                           tol: float):
    """A (n, d, C, N): ∫_texel A_n(γ) dγ of every texel (Gauss–Legendre,
    :data:`GAUSS_NODES`, on the exact Nyström extension of the directional
    light ``model``'s kernel, :func:`~integrators.epipolar.kernel.separation.separate_kernel`,
    evaluated at each texel's nodes, :func:`gauss_nodes`)
    and B (n, r, C, N) at the queries' β.
    Σ_n A_n B_n(β) is then the exact texel integral of K(·, β) (to the SVD
    tolerance): no per-query cell factor."""
    A3, B = separate_kernel(model.separation, params, queries, rays, rank, tol,
                            points=gauss_nodes(rays))
    n, d, C, N = queries.n, rays.d, A3.shape[2], A3.shape[3]
    n_g = len(GAUSS_NODES)
    CN = C * N
    j = dr.arange(mi.UInt32, n * d * CN)
    texel, cn = Divisor(CN).divmod(j)
    flat = mi.Float(A3.array)
    A = dr.zeros(mi.Float, n * d * CN)
    for g, wg in enumerate(GAUSS_WEIGHTS):
        A += wg * dr.gather(mi.Float, flat, (texel * n_g + g) * CN + cn)
    A *= dr.gather(mi.Float, rays.widths(), texel)
    return mi.TensorXf(A, shape=(n, d, C, N)), B


def projective_query_terms(params, cap, queries, rays: ProjectiveLightRays, V_near=1.0):
    """Per-query factors of the projective map (directional light):
    :func:`~integrators.epipolar.query_terms.directional_query_terms` with the
    view factor 1/sin β (each texel carries its own width) and the near
    term for a map that starts at its first edge γ_0 (t_0 = γ_0 / sin β)
    instead of at the eye: the rectified sum covers [t_0, t_end], the
    camera ray [t_near, t_end], so ∫_{t_0}^{t_near} (signed) is removed,
    lit as the first texel says (``V_near``) and with its light-side
    factor."""
    terms = directional_query_terms(params, cap, queries, rays, V_near)
    sigma_t = color(params.medium.sigma_t)
    sin_b = dr.sin(queries.beta)
    gamma0 = dr.gather(mi.Float, rays.inv_cos, queries.row) * dr.gather(mi.Float, rays.x_edges, 0)
    t0 = gamma0 / sin_b
    first = queries.row * rays.d
    dh = dr.gather(mi.Float, rays.h, first) - dr.gather(mi.Float, rays.h_ref, queries.row)
    k = sigma_t * (1.0 - dr.cos(queries.beta))
    near = V_near * dr.exp(-sigma_t * dh) * (segment_weight(k, 0.0, queries.t_near)
                                             - segment_weight(k, 0.0, t0))
    near = dr.select(dr.isfinite(dh), near, 0.0)
    view = dr.rcp(sin_b)
    return replace(terms, view=mi.Color3f(view, view, view), near=near)


def projective_map_rays(params, queries, rows: ProjectiveRows, d: int,
                        splits: int = 0) -> ProjectiveLightRays:
    """``d`` texels per row over the x range of the queries, in ``splits``
    splits (0: :func:`~rectify.projective.auto_splits`)."""
    x_lo, x_hi = projective_x_range(queries, rows)
    columns = projective_columns(x_lo, x_hi, d, splits or auto_splits(x_lo, x_hi))
    return projective_light_rays(params, queries, rows, columns)
