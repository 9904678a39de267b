"""Coarse unshadowed in-scattering of every sample (the ``inscattering``
refinement criterion): the section integral over the whole ray with
``V = 1`` and the light's base colour (no spot fall-off or texture)."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..core.light_transport import color, phase_eval
from ..core.opaque import vector
from .section_integral import box_path, directional_section, point_ray, point_section
from .slices_and_samples import EpipolarSamples


def unshadowed_inscattering(params, samples: EpipolarSamples, table) -> mi.Color3f:
    sigma_t, sigma_s = color(params.medium.sigma_t), color(params.medium.sigma_s)
    zero = dr.zeros(mi.Float, samples.size)
    E = color(params.light.radiance)
    if params.light.kind == "directional":
        w_l = vector(params.light.direction)
        f_p = phase_eval(params, samples.omega, w_l)
        L = directional_section(sigma_t, box_path(params, samples.o, samples.omega), zero,
                                samples.d)
        L = sigma_s * f_p * E * L
    else:
        ray = point_ray(params, samples.o, samples.omega)
        L = sigma_s * E * point_section(sigma_t, table, ray, zero, samples.d)
    return dr.select(samples.used, L, 0.0)
