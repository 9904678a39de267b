"""Hypothesis strategies of the tests: random cameras and lights, including
every degenerate configuration of :mod:`rectify.scenarios`."""
from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from rectify.scenarios import nasty_epipoles, rotated_camera, scenario


def scenario_strategy(min_width: int = 16, max_width: int = 48, min_height: int = 12,
                      max_height: int = 36):
    """Hypothesis strategy of ``(camera, light, label)`` over random cameras,
    image sizes, light kinds and all the degenerate configurations."""
    @st.composite
    def build(draw):
        W = draw(st.integers(min_width, max_width))
        H = draw(st.integers(min_height, max_height))
        ang = st.floats(-180, 180, allow_nan=False)
        cam = rotated_camera(
            origin=tuple(draw(st.floats(-20, 20, allow_nan=False)) for _ in range(3)),
            yaw_deg=draw(ang), pitch_deg=draw(st.floats(-85, 85)), roll_deg=draw(ang),
            fov_x_deg=draw(st.floats(20, 110)), width=W, height=H)
        kind = draw(st.sampled_from(["directional", "point", "spot"]))
        mode = draw(st.sampled_from(["random", "nasty", "nasty", "infinity", "axis"]))
        kw = dict(behind=draw(st.booleans()), distance=draw(st.floats(0.5, 200)))
        if mode == "nasty":
            kw["name"] = draw(st.sampled_from(sorted(nasty_epipoles(W, H))))
        elif mode == "infinity":
            kw["angle_deg"] = draw(st.one_of(st.sampled_from([0.0, 45.0, 90.0, 180.0]), ang))
        elif mode == "random":
            v = [draw(st.floats(-1, 1)) for _ in range(3)]
            if np.linalg.norm(v) < 1e-3:
                v = [0.0, 0.0, 1.0]
            kw["direction"] = tuple(v)
        light = scenario(cam, mode, kind, **kw)
        label = f"{mode}:{kw.get('name', '')} {kind} behind={kw['behind']} {W}x{H}"
        return cam, light, label

    return build()
