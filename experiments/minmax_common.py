"""Helpers the ``minmax_*`` experiments share (Yusov 2013's method).

- :func:`quality`: the DESIGN §2 error set at pixel centres against the exact
  working reference: scale-free relMSE, mean ratio (energy), largest pixel
  error over the reference's peak, FLIP;
- :func:`white_spot_scene`: a suite scene with its spot light's projected
  texture removed (white shafts, for the coloured-vs-white comparison);
- :func:`working_set_mb`: the arrays one render of ``minmax_epipolar``
  allocates (the talk's "Mem, MB" column, estimated from the sizes);
- :func:`stage_ms`: its stage times in milliseconds;
- :func:`scaled_run`: the common options plus ``--scale`` (a resolution
  factor for the machine at hand); :func:`write_results`: CSV + JSON + table.
"""
from __future__ import annotations

import os
import re
import tempfile

import numpy as np

from episcatter import metrics

#: stages of minmax_epipolar's scattering hook, in pipeline order
STAGES = ("shadowmap", "samples", "table", "refinement", "blockers", "tree", "integrate",
          "interpolate", "unwarp", "fixup")
CONVENTION = ("pixel centres: 1 sample per pixel at the pixel centre, against raymarch "
              "visibility=exact at the same positions")


def quality(img, ref) -> dict:
    """Scale-free relMSE, mean ratio, max |error| / peak, FLIP, NaN/Inf count."""
    img = np.asarray(img, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    finite = np.isfinite(img)
    peak = float(np.max(np.abs(ref))) or 1.0
    return {"relmse": metrics.scale_free_relmse(np.where(finite, img, 0.0), ref),
            "mean_ratio": metrics.mean_ratio(np.where(finite, img, 0.0), ref),
            "max_err_over_peak": float(np.max(np.abs(np.where(finite, img, 0.0) - ref))) / peak,
            "flip": metrics.flip(np.where(finite, img, 0.0), ref),
            "nonfinite": int(np.sum(~np.all(finite, axis=-1)))}


def white_spot_scene(scene_path: str) -> str:
    """Path of a copy of ``scene_path`` without the spot light's projected
    texture, written next to nothing the repository tracks (a temp folder);
    relative asset paths keep resolving through Mitsuba's file resolver."""
    import mitsuba as mi

    text = open(scene_path, encoding="utf-8").read()
    white = re.sub(r'<texture type="bitmap" name="texture">.*?</texture>', "", text, flags=re.S)
    folder = tempfile.mkdtemp(prefix="minmax_white_")
    path = os.path.join(folder, "white_" + os.path.basename(scene_path))
    with open(path, "w", encoding="utf-8") as f:
        f.write(white)
    mi.file_resolver().prepend(os.path.dirname(os.path.abspath(scene_path)))
    return path


def working_set_mb(stats: dict, width: int, height: int) -> float:
    """Estimated bytes of the render's arrays: per epipolar sample 41 B of
    geometry + 2×12 B of in-scattering (integrated, interpolated) + 12 B of
    sources; per light-ray texel 20 B (depth bounds, colour) and per tree
    node 32 B (2 depths, 2 colours, 2n nodes per slice); the point table;
    per pixel 12 B unwarped + 4 B weight.  Camera G-buffer and shadow map
    excluded (the talk's column excludes back/depth buffer and shadow map)."""
    s = stats["settings"]
    n = int(s["light_rays"])
    samples = stats["samples"]
    slices = stats["slices"]
    total = samples * (41 + 24 + 12) + slices * n * 20 + slices * 2 * n * 32 + 256 * 256 * 12 \
        + width * height * 16
    return total / 2 ** 20


def stage_ms(timings: dict) -> dict:
    return {f"{k}_ms": 1e3 * float(timings[k]) for k in STAGES if k in timings}


def scaled_run(doc: str, settings_for, name: str, argv, scenes: list, quick_scenes: list,
               add_arguments=None):
    """(args, settings, repeats, out) of an experiment with ``--scale``
    (``add_arguments(parser)``: the experiment's own options)."""
    from . import common as c

    p = c.base_parser(doc, scenes, quick_scenes)
    p.add_argument("--scale", type=float, default=None, help="resolution factor")
    if add_arguments is not None:
        add_arguments(p)
    args = p.parse_args(argv)
    s = c.sized(settings_for(args.quick), args.size)
    if args.scale:
        s["scale"] = args.scale
    return args, s, args.repeats or (1 if args.quick else 3), c.output_dir(name, args.out,
                                                                          args.quick)


def write_results(out, settings: dict, rows: list, text: str, **extra) -> None:
    """``runs.csv``, ``runs.json`` (settings, environment, rows, ``extra``)
    and ``table.md``; each list in ``extra`` also as ``<key>.csv``."""
    from . import common as c

    c.write_csv(out / "runs.csv", rows)
    for key, value in extra.items():
        if isinstance(value, list):
            c.write_csv(out / f"{key}.csv", value)
    c.write_json(out / "runs.json", settings, rows, **extra)
    c.write_text(out / "table.md", text)
