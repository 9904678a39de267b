"""Partial renders (DESIGN §4): the mask of camera samples a render is asked
for and the merge with the previous frame (:mod:`.samples`), what changed
between frames (:mod:`.change_mask`), and the epipolar rows whose inputs
changed (:mod:`.row_subset`).  ``minmax_epipolar``'s slices are its own
(:mod:`integrators.minmax.slice_subset`).
"""
