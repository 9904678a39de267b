"""The light-ray layout protocol: the texels of a rectified map's row, as
every stage after the layout reads them (DESIGN §3).
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from ...core.opaque import Divisor
from ..queries import frame_memo


# --------------------------------------------------------------------------
# Light rays (§3, §5)
# --------------------------------------------------------------------------

class LightRayLayout:
    """The light-ray layout protocol: what every stage after the light rays
    (blockers, light factor, kernel, sweep, query terms) may read.

    Every layout is a frozen dataclass with the fields ``d`` (light rays per
    row, the sweep's leaves), ``gamma_max`` (n,) (each row's last γ) and
    ``delta_gamma`` (n,) (each row's light-ray width; the mean width where
    they are unequal), and the methods :meth:`lanes`, :meth:`positions` and
    :meth:`row_counts`, and what a stage asks of any layout instead of
    testing its type: :attr:`equal_widths`, :meth:`query_depth`,
    :meth:`texel_weights`, :meth:`own_kernel` and :meth:`read_blockers`.
    Layouts: :class:`~integrators.epipolar.light_rays.directional.LightRays` (directional),
    :class:`~integrators.epipolar.light_rays.local.LocalLightRays` (point/spot),
    :class:`~integrators.fourier.projective_rays.ProjectiveLightRays` (Klehm §4.2)."""

    #: whether every row's light rays are equally wide (from ``γ_lo``, see
    #: :class:`EqualLightRays`): what sub-rays, geometric kernel steps and
    #: traced ends need
    equal_widths = False

    def lanes(self, per_ray: int = 1):
        """(row s, light ray g, sub-ray m) of ``n·d·per_ray`` lanes."""
        n = dr.width(self.delta_gamma)
        j = dr.arange(mi.UInt32, n * self.d * per_ray)
        return (Divisor(self.d * per_ray).div(j), Divisor(self.d).divmod(j // per_ray)[1],
                j % per_ray)

    def positions(self, offset: float = 0.5):
        """(row, γ) of every light ray at ``offset`` ∈ [0, 1] across its
        interval (0.5: its centre, 0: its start), (n·d,) lanes."""
        raise NotImplementedError

    def position(self, s, g, offset: float = 0.5) -> mi.Float:
        """γ of light ray ``g`` of rows ``s`` (per lane) at ``offset``, as
        :meth:`positions` gives it at lane ``s·d + g``."""
        raise NotImplementedError

    def row_counts(self):
        """(n,) light rays that exist per row, or None: all ``d``."""
        return None

    def query_depth(self, queries) -> mi.Float:
        """D (Q,): each query's end point as a fractional light-ray index
        (§5; clipped to [0, d] by its users)."""
        raise NotImplementedError

    def texel_weights(self):
        """(n·d,) weight of each light ray in a row's average: its width,
        or 1 where a row's light rays are equally wide (the widths cancel)."""
        return 1.0

    def own_kernel(self, sigma_t: float):
        """``K(texel, tan(β/2))`` where the layout fixes the kernel of a
        light ray itself (unequal texels: their exact integral), else None:
        the light model's ``ray_kernel``."""
        return None

    def read_blockers(self, read, params, queries, *args, **kw) -> mi.Float:
        """β_b of every light ray: ``read(params, queries, rays, *args)``,
        the light model's traced or resampled blockers."""
        return read(params, queries, self, *args, **kw)


def rectified_depth(queries, rays: "EqualLightRays") -> mi.TensorXf:
    """D (n, r): each query's depth as a fractional light-ray index (§5),
    ``(γ_end − γ_lo) / Δγ`` (clipped to [0, d] by the sweep)."""
    D = ((queries.gamma_end - rays.start(queries.row))
         / dr.gather(mi.Float, rays.delta_gamma, queries.row))
    return mi.TensorXf(queries.padded(D, 0.0), shape=(queries.n, queries.r))


def covered_depth(queries, rays, d_o) -> tuple:
    """(D, k0) per query: its depth ``rays.query_depth`` as a fractional
    light-ray index clipped to [0, d] (NaN: 0) and the last light ray it
    (partly) covers in its row, k0 = min(⌊D⌋, d − 1); ``d_o``: d as an
    opaque kernel parameter."""
    D = rays.query_depth(queries)
    D = dr.clip(dr.select(dr.isnan(D), 0.0, D), 0.0, mi.Float(d_o))
    return D, dr.minimum(mi.UInt32(D), d_o - 1)


class EqualLightRays(LightRayLayout):
    """Equally wide light rays from each row's ``γ_lo``: leaf ``g`` covers
    ``γ_lo + [g, g+1)·Δγ``.  Adds the field ``gamma_lo`` ((n,) or None: 0)
    and :meth:`start`; what the sub-ray, rectified-depth and blocker-mode
    functions need."""

    equal_widths = True

    def start(self, s) -> mi.Float:
        """γ_lo of rows ``s`` (0 when the rows start at the axis)."""
        if self.gamma_lo is None:
            return dr.zeros(mi.Float, dr.width(s))
        return dr.gather(mi.Float, self.gamma_lo, s)

    def positions(self, offset: float = 0.5):
        s, g, _ = self.lanes()
        return s, self.position(s, g, offset)

    def position(self, s, g, offset: float = 0.5) -> mi.Float:
        """γ of light ray ``g`` of rows ``s`` at ``offset`` across its interval."""
        return self.start(s) + (mi.Float(g) + offset) * dr.gather(mi.Float, self.delta_gamma, s)

    def query_depth(self, queries) -> mi.Float:
        return dr.gather(mi.Float, rectified_depth(queries, self).array, queries.slot)


#: :func:`~integrators.epipolar.queries.frame_memo` key of the smallest
#: finite light-side path of a frame's light rays (None: none finite)
LOWEST_LIGHT_SIDE = "lowest_light_side"


def finite_or_inf(path) -> mi.Float:
    """``path`` where finite, else +inf: its minimum is the smallest finite
    light-side path (+inf: none)."""
    return dr.select(dr.isfinite(path), path, dr.inf)


def lowest_or_none(lowest: float) -> float | None:
    """The minimum of :func:`finite_or_inf`, None where no path is finite."""
    return None if lowest == math.inf else lowest


def keep_lowest_light_side(queries, rays, lowest: float) -> None:
    """Keep the smallest finite light-side path ``lowest`` (inf: none) of
    ``rays``, found by the kernel that made them, for
    :func:`~integrators.epipolar.light_factor.lowest_light_side`."""
    frame_memo(queries, (LOWEST_LIGHT_SIDE, rays), lambda: lowest_or_none(lowest))
