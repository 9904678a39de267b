"""The light-ray layout protocol: the texels of a rectified map's row, as
every stage after the layout reads them (DESIGN §3).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ...core.opaque import Divisor


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
    :meth:`row_counts`.  Layouts: :class:`LightRays` (directional),
    :class:`~integrators.epipolar.light_rays.local.LocalLightRays` (point/spot),
    :class:`~integrators.fourier.projective_rays.ProjectiveLightRays` (Klehm §4.2)."""

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

    def row_counts(self):
        """(n,) light rays that exist per row, or None: all ``d``."""
        return None


class EqualLightRays(LightRayLayout):
    """Equally wide light rays from each row's ``γ_lo``: leaf ``g`` covers
    ``γ_lo + [g, g+1)·Δγ``.  Adds the field ``gamma_lo`` ((n,) or None: 0)
    and :meth:`start`; what the sub-ray, rectified-depth and blocker-mode
    functions need."""

    def start(self, s) -> mi.Float:
        """γ_lo of rows ``s`` (0 when the rows start at the axis)."""
        if self.gamma_lo is None:
            return dr.zeros(mi.Float, dr.width(s))
        return dr.gather(mi.Float, self.gamma_lo, s)

    def positions(self, offset: float = 0.5):
        s, g, _ = self.lanes()
        return s, self.start(s) + (mi.Float(g) + offset) * dr.gather(mi.Float, self.delta_gamma, s)
