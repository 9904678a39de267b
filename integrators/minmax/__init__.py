"""Stages of ``minmax_epipolar`` (Yusov 2013), one module each, in pipeline
order; each stage function returns a frozen dataclass an experiment can
inspect:

- :mod:`.slices_and_samples` — slices, rescaled samples, traced camera rays
  (:class:`~integrators.minmax.slices_and_samples.EpipolarSamples`);
- :mod:`.refinement` — initial samples, break criteria, interpolation
  sources (:class:`~integrators.minmax.refinement.Sources`);
- :mod:`.light_rays` — the 1D height map of every slice, traced or
  resampled (:class:`~integrators.minmax.light_rays.SliceLightRays`);
- :mod:`.minmax_tree` — tree build and march (:class:`~integrators.minmax.minmax_tree.MinMaxTree`,
  :class:`~integrators.minmax.minmax_tree.MarchResult`), with the per-texel NumPy oracle;
- :mod:`.section_integral` — in-scattering of a lit section (directional
  closed form, point/spot table :class:`~integrators.minmax.section_integral.PointTable`);
- :mod:`.integrate` — the march of the integration samples
  (:class:`~integrators.minmax.integrate.Integrated`); :mod:`.unscattered` — coarse unshadowed
  values;
- :mod:`.unwarp` — bilateral unwarp and fix-up (:class:`~integrators.minmax.unwarp.Unwarped`);
- :mod:`.profiles` — the talk's quality profiles; :mod:`.validate` —
  refused inputs.
"""
