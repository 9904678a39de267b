"""Per-slice partial renders (integrators.partial.row_subset): the slices a moved box
can reach against a dense NumPy oracle, partial renders that compute a few
rows and equal the full render there, and a frame whose frame-wide choices
changed rendered in full."""
from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from episcatter.motion import parse_motion
from episcatter.sequence import Sequence
from integrators.core.shadow_volumes import Boxes
from integrators.epipolar.frame import epipolar_frame_of
from integrators.partial.row_subset import in_arcs, slice_arcs, slice_meets_boxes_reference
from integrators.core.scene_params import SceneParams
from tests.conftest import scene_dict
from tests.test_sequence import MOTIONS, animated_scene, full_render


@pytest.mark.parametrize("light", ["directional", "point", "spot"])
def test_slice_arcs_match_the_dense_oracle(light):
    params = SceneParams.from_scene(mi.load_dict(scene_dict(light=light, res=(16, 12))))
    frame = epipolar_frame_of(params)
    rng = np.random.default_rng(3)
    centre = rng.uniform(-1.5, 1.5, (4, 3))
    size = rng.uniform(0.05, 0.6, (4, 3))
    alphas = np.linspace(-np.pi, np.pi, 91)[:-1]
    checked = 0
    for lo, hi in zip(centre - size, centre + size):
        boxes = Boxes(lo[None], hi[None])
        arcs = slice_arcs(frame, boxes)
        fast = in_arcs(alphas, arcs)
        slow = np.array([slice_meets_boxes_reference(frame, a, boxes) for a in alphas])
        assert np.all(fast[slow]), "a slice meeting the box was left out"
        # the oracle's grid may miss a slice that only grazes the box
        extra = np.flatnonzero(fast & ~slow)
        assert len(extra) <= 2, (arcs, extra)
        checked += slow.sum()
    assert checked > 0


def test_a_box_around_the_axis_reaches_every_slice():
    params = SceneParams.from_scene(mi.load_dict(scene_dict(light="point", res=(16, 12))))
    frame = epipolar_frame_of(params)
    eye = np.asarray(frame.camera.origin, np.float64)
    towards = eye + 0.5 * np.asarray(frame.axis, np.float64)
    assert slice_arcs(frame, Boxes((towards - 0.1)[None], (towards + 0.1)[None])) is None
    assert slice_arcs(frame, Boxes.empty()) == []


@pytest.mark.parametrize("light", ["directional", "spot", "point"])
@pytest.mark.parametrize("props", [{"type": "epipolar_tree"}, {"type": "fourier_filter"},
                                   {"type": "fourier_filter", "visibility": "filter"}])
def test_a_few_masked_samples_compute_their_slices_alone(props, light):
    """A partial render of a few samples computes the rows holding them
    (both neighbours with slice interpolation) -- far fewer than all
    samples -- and equals the full render on every computed sample
    (``fourier_filter``: its rows, with the filter or the exact sum)."""
    scene = mi.load_dict(scene_dict(light=light, res=(40, 30)))
    integ = mi.load_dict(props)
    full = integ.render_layers(scene)
    mask = np.zeros(1200, bool)
    mask[[305, 611, 917]] = True
    part = integ.render_layers(scene, samples=mask)
    computed = np.array(part.samples, dtype=bool)
    print(f"{light}: {computed.sum()} of 1200 samples computed, rows "
          f"{part.stats['rows_computed']} of {part.stats['rows']}")
    assert computed[mask].all() and computed.sum() < 0.5 * computed.size
    assert part.stats["rows_computed"] < part.stats["rows"]
    a, b = np.array(full.L_scat), np.array(part.L_scat)
    # exactly: a row's values must not depend on which other rows are computed
    np.testing.assert_array_equal(b[:, computed], a[:, computed])
    assert part.stats["frame_choices"] == full.stats["frame_choices"]


def test_changed_frame_choices_render_the_whole_frame():
    """If the frame-wide choices of a reused frame differ from the previous
    frame's, the kept samples are stale: the frame is rendered in full."""
    scene = animated_scene("directional")
    integ = mi.load_dict({"type": "epipolar_tree"})
    record, count = integ.record, [0]

    def new_choices(**stats):            # every render makes other choices
        if "frame_choices" in stats:
            count[0] += 1
            stats["frame_choices"] = count[0]
        record(**stats)
    integ.record = new_choices
    seq = Sequence(scene, integ, [parse_motion(MOTIONS["translate"])], frames=3)
    for frame in seq:
        full = full_render(scene, mi.load_dict({"type": "epipolar_tree"}))
        np.testing.assert_allclose(frame.layers["full"], full["full"], rtol=1e-6,
                                   atol=1e-7 * full["full"].max())
        if frame.index:
            assert frame.whole_frame == ["frame choices"] and frame.recomputed == frame.samples


def test_the_last_frames_rectification_is_reused_where_it_holds():
    """A partial render handed an earlier render's ``frame_state`` keeps its
    queries (γ_end recomputed from the new d) and equals the full render."""
    scene = mi.load_dict(scene_dict(light="spot", res=(40, 30)))
    integ = mi.load_dict({"type": "epipolar_tree"})
    full = integ.render_layers(scene)
    mask = np.zeros(1200, bool)
    mask[[100, 640]] = True
    part = integ.render_layers(scene, samples=mask, known=full.capture,
                               frame_state=full.frame_state)
    assert part.stats.get("rectification_reused") and part.frame_state is not None
    computed = np.array(part.samples, dtype=bool)
    np.testing.assert_allclose(np.array(part.L_scat)[:, computed],
                               np.array(full.L_scat)[:, computed], rtol=1e-6, atol=1e-9)
    fresh = integ.render_layers(scene, samples=mask)      # no state: rectified anew
    assert "rectification_reused" not in fresh.stats
