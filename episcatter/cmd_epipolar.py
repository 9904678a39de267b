"""``episcatter epipolar SCENE [-D name=value]... [--light N] [--ring DEG] [--json] [--png OUT.png [--image EXR]]``

Epipolar geometry of a scene's camera and light (rectify issue, point 8): the
epipole in pixel coordinates and its case (on-screen / off-screen / at
infinity / behind the camera), the slice counts of Baran's ``sinh``
distribution (§8, Eq. 5) and of uniform 1-px border spacing, the largest
distance from any pixel centre to its nearest slice line for each, and the
number of pixels in the epipole ring (§6).  ``--png`` draws the slices, the
epipole and the ring over ``--image`` (an EXR of the scene) or a quick
preview render (:mod:`episcatter.epipolar_overlay`).
"""
from __future__ import annotations

import json

from .scene_loading import load_scene, parse_assignments


def add_arguments(p):
    p.add_argument("scene", help="Mitsuba XML scene file")
    p.add_argument("-D", "--define", action="append", default=[], metavar="NAME=VALUE",
                   help="XML default, e.g. -D res_x=1280 (repeatable)")
    p.add_argument("--ring", type=float, default=2.0, help="epipole ring radius in degrees")
    p.add_argument("--light", type=int, default=0, metavar="N",
                   help="which of the scene's lights (0: the first; each light has its own "
                        "epipolar geometry)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--png", metavar="OUT.png",
                   help="draw the slices, the epipole and the ring over the image into a PNG")
    p.add_argument("--image", metavar="EXR",
                   help="image to draw on (default: a quick 1-spp raymarch preview)")
    p.add_argument("--lines", type=int, default=48, help="slice lines drawn at most (--png)")


def light_geometry(params, index: int = 0):
    """(kind, direction or position) of the scene's light ``index``, as
    rectify takes it."""
    if not 0 <= index < len(params.lights):
        raise ValueError(f"--light {index}: the scene has {len(params.lights)} light(s); "
                         f"give 0..{len(params.lights) - 1}.")
    light = params.lights[index]
    return (("directional", light.direction) if light.kind == "directional"
            else (light.kind, light.position))


def scene_geometry(scene_path, defines=None, ring_deg=2.0, light=0) -> dict:
    """rectify.describe() of a scene file's camera and its light ``light``."""
    from integrators.core.scene_params import SceneParams
    from rectify.describe import describe

    params = SceneParams.from_scene(load_scene(scene_path, defines))
    info = describe(params.camera, light_geometry(params, light), ring_deg=ring_deg)
    info["scene"] = scene_path
    info["light"], info["lights"] = light, len(params.lights)
    return info


def write_overlay(args, defines) -> dict:
    """The ``--png`` drawing (:func:`episcatter.epipolar_overlay.draw_overlay`)."""
    from integrators.core.scene_params import SceneParams
    from rectify.epipole import epipolar_frame

    from .epipolar_overlay import draw_overlay, preview_image
    from .imageio import read_rgb

    scene = load_scene(args.scene, defines)
    params = SceneParams.from_scene(scene)
    frame = epipolar_frame(params.camera, light_geometry(params, args.light))
    rgb = read_rgb(args.image) if args.image else preview_image(scene)
    if rgb.shape[:2] != (frame.height, frame.width):
        raise ValueError(f"--image is {rgb.shape[1]}x{rgb.shape[0]} but the scene renders "
                         f"{frame.width}x{frame.height}: pass the same -D res_x/res_y.")
    return draw_overlay(args.png, rgb, frame, args.ring, args.lines)


def run(args) -> int:
    defines = parse_assignments(args.define)
    if args.png:
        from .imageio import output_paths
        if output_paths(args.png)[1] != args.png:
            raise ValueError(f"--png '{args.png}' must end in .png.")
    info = scene_geometry(args.scene, defines, args.ring, args.light)
    if args.png:
        info["drawing"] = write_overlay(args, defines)
        if not args.json:
            d = info["drawing"]
            print(f"wrote {args.png}: {d['lines']} of {d['slices']} slices, epipole "
                  f"{'marked' if d['epipole_marked'] else 'off the picture (arrow)'}, "
                  f"ring {d['ring_pixels']} px")
    if args.json:
        print(json.dumps(info, indent=2, default=str))
        return 0
    ex, ey = info["epipole_px"]
    rows = [
        ("scene", info["scene"]),
        ("image", f"{info['width']}x{info['height']}"),
        ("light", f"{info['light_kind']} ({info['light']} of {info['lights']})"),
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
