"""``episcatter epipolar SCENE [-D name=value]... [--ring DEG] [--json]``

Epipolar geometry of a scene's camera and light (rectify issue, point 8): the
epipole in pixel coordinates and its case (on-screen / off-screen / at
infinity / behind the camera), the slice counts of Baran's ``sinh``
distribution (§8, Eq. 5) and of uniform 1-px border spacing, the largest
distance from any pixel centre to its nearest slice line for each, and the
number of pixels in the epipole ring (§6).
"""
from __future__ import annotations

import json

from .scene_loading import load_scene, parse_assignments


def add_arguments(p):
    p.add_argument("scene", help="Mitsuba XML scene file")
    p.add_argument("-D", "--define", action="append", default=[], metavar="NAME=VALUE",
                   help="XML default, e.g. -D res_x=1280 (repeatable)")
    p.add_argument("--ring", type=float, default=2.0, help="epipole ring radius in degrees")
    p.add_argument("--json", action="store_true", help="print JSON")


def scene_geometry(scene_path, defines=None, ring_deg=2.0) -> dict:
    """rectify.describe() of a scene file's camera and light."""
    from integrators.scene_params import SceneParams
    from rectify.describe import describe

    params = SceneParams.from_scene(load_scene(scene_path, defines))
    light = params.light
    geom = (("directional", light.direction) if light.kind == "directional"
            else (light.kind, light.position))
    info = describe(params.camera, geom, ring_deg=ring_deg)
    info["scene"] = scene_path
    return info


def run(args) -> int:
    info = scene_geometry(args.scene, parse_assignments(args.define), args.ring)
    if args.json:
        print(json.dumps(info, indent=2, default=str))
        return 0
    ex, ey = info["epipole_px"]
    rows = [
        ("scene", info["scene"]),
        ("image", f"{info['width']}x{info['height']}"),
        ("light", info["light_kind"]),
        ("epipole (px)", f"({ex:.2f}, {ey:.2f})"),
        ("case", info["case"]),
        ("slices, sinh", info["slices_sinh"]),
        ("slices, uniform", f"{info['slices_uniform']}  (sinh saves "
                            f"{100 * info['sinh_saving']:.1f} %)"),
        ("max px-to-slice, sinh", f"{info['max_distance_px_sinh']:.4f} px"),
        ("max px-to-slice, uniform", f"{info['max_distance_px_uniform']:.4f} px"),
        (f"ring pixels ({info['ring_deg']:g} deg)", info["ring_pixels"]),
        ("projective rectification", info["projective"]),
    ]
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k:<{width}}  {v}")
    return 0
