"""The light-ray layout of each rectified row: one protocol
(:class:`.layout.LightRayLayout`) read by every later stage, and its
layouts: :mod:`.directional` (rays parallel to the light direction) and
:mod:`.local` (rays from a point or spot light; a spot light's cone).
Klehm's projective layout is :mod:`integrators.fourier.projective_rays`.
"""
