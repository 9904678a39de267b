"""Write the scene suite: ``python -m scenes.generate [--force-assets]``.

Rewrites every ``scenes/<name>.xml`` and ``scenes/<name>_lit.xml`` from
:mod:`scenes.catalog`, :mod:`scenes.fourier_stress` and
:mod:`scenes.several_lights` and builds the generated meshes and textures that are
missing or out of date (:func:`scenes.assets.ensure_assets`).  Deterministic:
fixed seeds, fixed number formatting, so the same code writes the same bytes.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from . import assets, catalog, fourier_stress, several_lights
from .meshes import write_atomic

LIT_SUFFIX = "_lit"


def scene_texts() -> dict[str, str]:
    """``{file stem: XML text}`` for every scene and its ``_lit`` variant."""
    texts = {}
    for name, build in {**catalog.SCENES, **fourier_stress.SCENES,
                        **several_lights.SCENES}.items():
        texts[name] = build(lit=False).to_string()
        texts[name + LIT_SUFFIX] = build(lit=True).to_string()
    return texts


def write_scenes(directory: Path = assets.SCENE_DIR) -> list[Path]:
    """Write all scene XML files into ``directory``; returns their paths."""
    paths = []
    for stem, text in scene_texts().items():
        path = Path(directory) / f"{stem}.xml"
        write_atomic(path, text.encode("utf-8"))
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m scenes.generate",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--force-assets", action="store_true",
                        help="rebuild meshes and textures even when up to date")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    paths = write_scenes()
    print(f"wrote {len(paths)} scene files to {assets.SCENE_DIR}", file=sys.stderr)
    assets.ensure_assets(force=args.force_assets)
    print(f"done in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
