"""Stage "integrate": in-scattering of the chosen integration samples by the
min/max-tree march (Yusov 2013, "Volumetric Shadows" + "1D min/max binary
trees"), each lit section closed-form (directional) or from the table
``C(h, φ)`` (point/spot), :mod:`.section_integral`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi

from rectify import view_to_light

from ..core.light_transport import color, first_blocker, phase_eval
from ..core.opaque import floats, scalar, vector
from .light_rays import SliceLightRays, texel_colour, texel_rays, traced_bias
from .minmax_tree import MinMaxTree, SliceRays, march_tree
from .section_integral import PointTable, box_path, directional_section, point_ray, point_section
from .slices_and_samples import EpipolarSamples


@dataclass(frozen=True, eq=False)
class Integrated:
    """L_scat of the integration samples ``index`` (flat sample indices)."""
    index: mi.UInt32 = field(repr=False)
    L: mi.Color3f = field(repr=False)
    steps: mi.UInt32 = field(repr=False)


def slice_rays(samples: EpipolarSamples, index: mi.UInt32) -> SliceRays:
    k = dr.gather(mi.UInt32, samples.slice, index)
    alpha = dr.gather(mi.Float, floats(samples.slices.alpha), k)
    return SliceRays(k=k, beta=dr.gather(mi.Float, samples.beta, index),
                     t_near=dr.gather(mi.Float, samples.t_near, index),
                     t_end=dr.gather(mi.Float, samples.d, index), alpha=alpha)


def integrate_samples(params, samples: EpipolarSamples, index: mi.UInt32,
                      light_rays: SliceLightRays, tree: MinMaxTree, table: PointTable | None,
                      max_level: int | None = None, shadow_map=None) -> Integrated:
    """March the samples ``index`` through their slices' trees."""
    rays = slice_rays(samples, index)
    o = dr.gather(mi.Point3f, samples.o, index)
    omega = dr.gather(mi.Vector3f, samples.omega, index)
    sigma_t, sigma_s = color(params.medium.sigma_t), color(params.medium.sigma_s)
    leaf = end = None
    if shadow_map is not None:
        def leaf(t, i):
            return shadow_map.visibility(o + omega * t)
    else:
        def end(t):
            return traced_visibility(params, samples.frame, light_rays, rays, t)
    if params.light.kind == "directional":
        path = box_path(params, o, omega)
        w_l = vector(params.light.direction)
        F = sigma_s * phase_eval(params, omega, w_l) * color(params.light.radiance)

        def section(a, b):
            return directional_section(sigma_t, path, a, b)
    else:
        ray = point_ray(params, o, omega)
        F = sigma_s

        def section(a, b):
            return point_section(sigma_t, table, ray, a, b)
    res = march_tree(samples.frame, light_rays, tree, rays, section, max_level, leaf,
                     end_visibility=end)
    return Integrated(index=index, L=F * res.L, steps=res.steps)


def traced_visibility(params, frame, light_rays: SliceLightRays, rays: SliceRays, t):
    """(V, colour): the visibility (0 or 1) of the point ``t`` of each ray
    by the height map's own test (:mod:`.light_rays`: depth ≤ traced blocker
    depth + bias) along the point's own light ray, traced with Mitsuba, and
    the light's colour along that ray (:func:`.light_rays.texel_colour`;
    :func:`~integrators.minmax.minmax_tree.march_tree`'s ``end_visibility``)."""
    gamma, u = view_to_light(frame, rays.alpha, rays.beta, rays.t_near + t)
    u_top = scalar(light_rays.u_top)
    o, w = texel_rays(frame, rays.alpha, gamma, light_rays.u_top)
    hit, p = first_blocker(params, o, w)
    z_b = dr.select(hit, dr.norm(p - o), dr.inf)
    if frame.is_directional:
        z, z_b = u_top - u, z_b + scalar(light_rays.bias)
    else:
        z, z_b = u, z_b + traced_bias(frame, z_b)
    V = dr.select(z <= z_b, mi.Float(1.0), mi.Float(0.0))
    return V, texel_colour(params, frame, o, w)
