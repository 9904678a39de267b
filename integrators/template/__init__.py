"""The integrator base classes: :mod:`.base` (every plugin: properties,
capture, layers, partial renders, timings) and :mod:`.epipolar` (the
epipolar plugins ``epipolar_tree`` and ``fourier_filter``: slices,
queries, ring and re-march).
"""
