"""Render the small volpath references shipped in ``references/``.

They back the README's first command (the error it prints) and the test
``tests/test_volpath_agreement.py``.  Run ``python -m experiments.make_shipped_references``
(a few minutes on 2 cores); every EXR has a JSON sidecar saying how it was made
(spp, seeds, time, its own noise from two independent halves, versions).
"""
from __future__ import annotations

import argparse

from episcatter.reference import SHIPPED_DIR, render_reference

#: (scene stem, defines, spp): the suite renders the agreement test uses,
#: covering directional / textured spot / point lights and isotropic / HG
#: g = +0.5 / -0.5 phase functions, dark and lit surfaces.
AGREEMENT = [
    ("nave_offscreen_lit", {"res_x": 48, "res_y": 36, "g": 0.5}, 65536),
    ("nave_offscreen", {"res_x": 48, "res_y": 36, "g": -0.5}, 65536),
    ("spot_room_lit", {"res_x": 48, "res_y": 36}, 65536),
    ("point_fog", {"res_x": 48, "res_y": 36}, 65536),
    ("beam", {"res_x": 48, "res_y": 36}, 65536),
]
#: the README's first image
DEFAULT_IMAGE = [("nave_offscreen", {"res_x": 160, "res_y": 120}, 16384)]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--only", help="render only this scene stem")
    parser.add_argument("--force", action="store_true")
    args = parser.parse_args(argv)
    import scenes
    for stem, defines, spp in AGREEMENT + DEFAULT_IMAGE:
        if args.only and stem != args.only:
            continue
        rgb, info = render_reference(scenes.path(stem), defines, spp=spp, chunk=1024,
                                     cache_dir=SHIPPED_DIR, force=args.force)
        print(f"{stem} {defines}: {info['spp']} spp, {info['wall_time_s']:.1f} s, "
              f"noise relMSE block1 {info['relmse_noise']['block_1']:.2e} "
              f"block4 {info['relmse_noise']['block_4']:.2e}")


if __name__ == "__main__":
    main()
