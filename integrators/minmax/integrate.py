"""Stage "integrate": in-scattering of the chosen integration samples by the
min/max-tree march (Yusov 2013, "Volumetric Shadows" + "1D min/max binary
trees"), each lit section closed-form (directional) or from the table
``C(h, φ)`` (point/spot), :mod:`.section_integral`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi

from ..light_transport import color, phase_eval
from .light_rays import SliceLightRays
from .minmax_tree import MinMaxTree, SliceRays, march_tree
from ..opaque import floats, vector
from .section_integral import (PointTable, box_path, directional_section, point_ray,
                               point_section)
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
    leaf = None
    if shadow_map is not None:
        def leaf(t, i):
            return shadow_map.visibility(o + omega * t)
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
    res = march_tree(samples.frame, light_rays, tree, rays, section, max_level, leaf)
    return Integrated(index=index, L=F * res.L, steps=res.steps)
