"""Epipolar slice counts of the suite at 1280x960 (rectify issue, point 4).

For every suite scene, :func:`episcatter.cmd_epipolar.scene_geometry`
(= :func:`rectify.describe.describe` of the scene's camera and light): the
epipole (pixels) and its case, the slice counts of Baran's ``sinh``
distribution (§8, Eq. 5) and of uniform 1-px spacing along the image edges
the slices leave through, the saving of ``sinh``, the largest distance from
any pixel centre to its nearest slice line for both (the half-pixel bound),
and the pixels of the 2° epipole ring (§6).

For comparison with Baran et al. 2010, the same quantities for synthetic
directional lights whose epipole sits at chosen places of a 1280x960 image
(60° horizontal field of view; the slice counts depend only on the epipole's
position, not on the field of view): the centre (where the paper reports
the smallest saving), near a corner (where it reports half), an edge, just
off-screen, far off-screen and at infinity.  The paper's figures, quoted in
``PAPER`` with the lines of /work/shared/papers/baran2010-hierarchical-volumetric-shadows.txt
they come from:

- §8: "when the epipole is on the screen near a corner, we get by with half
  the number of slices.  We get the least savings when the epipole is in
  the center of the screen, resulting in 15% fewer slices (in 1280 × 960
  resolution) than uniform sampling" -- "always maintaining a half-pixel
  bound on sampling error";
- §10 (methodology): "All images are rendered at 1280 × 960 ... The number
  of epipolar slices chosen by the adaptive distribution algorithm varies
  between 2116-2264";
- §10.2 (GPU): "Our adaptive distribution algorithm would only require 700 –
  800 slices to obtain the same sampling density" as 1024 slices.

Writes ``results/slice_counts/``: ``table.md``, ``slice_counts.csv``,
``slice_counts.json``.  ``python -m experiments.slice_counts [--quick]
[--width 1280 --height 960] [--scenes ...]``; pure geometry, seconds.
"""
from __future__ import annotations

import time

from . import common as c

NAME = "slice_counts"
PAPER_FILE = "/work/shared/papers/baran2010-hierarchical-volumetric-shadows.txt"
PAPER = [
    {"what": "saving of sinh over uniform, epipole at the image centre, 1280x960",
     "value": "15 %", "where": "§8, line 220"},
    {"what": "saving of sinh over uniform, epipole on screen near a corner",
     "value": "about 50 % ('half the number of slices')", "where": "§8, line 220"},
    {"what": "sinh slice count of the paper's three scenes (SIBENIK, TREES, LANDSCAPE) "
             "at 1280x960", "value": "2116-2264", "where": "§10, line 232"},
    {"what": "sinh slices for the sampling density of 1024 slices (GPU comparison, "
             "TREES and SIBENIK)", "value": "700-800", "where": "§10.2, line 276"},
]

#: synthetic epipole positions, as fractions of (width, height) or named
SYNTHETIC = [
    ("centre", (0.5, 0.5)),
    ("quarter", (0.25, 0.25)),
    ("near corner (5 %)", (0.05, 0.05)),
    ("corner + 0.5 px", "corner"),
    ("edge midpoint", (0.5, 0.0)),
    ("just off the left edge", "off_left"),
    ("off screen, 1 image away", (-1.0, 0.5)),
    ("far off screen (7 images)", (-7.0, 2.0)),
    ("at infinity (light parallel to film)", "infinity"),
]


def geometry_row(info: dict) -> dict:
    """The table's columns from a describe() dict."""
    return {"light": info["light_kind"], "case": info["case"],
            "epipole_x": info["epipole_px"][0], "epipole_y": info["epipole_px"][1],
            "slices_sinh": info["slices_sinh"], "slices_uniform": info["slices_uniform"],
            "saving": info["sinh_saving"],
            "max_px_sinh": info["max_distance_px_sinh"],
            "max_px_uniform": info["max_distance_px_uniform"],
            "ring_pixels": info["ring_pixels"],
            "ring_fraction": info["ring_pixels"] / (info["width"] * info["height"]),
            "projective": info["projective"]}


def suite_rows(names, width: int, height: int) -> list[dict]:
    from episcatter.cmd_epipolar import scene_geometry

    rows = []
    for name in names:
        t0 = time.perf_counter()
        info = scene_geometry(c.scene_file(name), c.resolution(width, height))
        rows.append({"kind": "scene", "name": name, **geometry_row(info),
                     "seconds": time.perf_counter() - t0})
        print(f"{name}: {rows[-1]['slices_sinh']} sinh / {rows[-1]['slices_uniform']} uniform",
              flush=True)
    return rows


def synthetic_rows(width: int, height: int) -> list[dict]:
    """The epipole placements of ``SYNTHETIC`` on a 60° camera."""
    from rectify.describe import describe
    from rectify.scenarios import light_parallel_to_image, light_toward_pixel, rotated_camera

    cam = rotated_camera(yaw_deg=20.0, pitch_deg=-10.0, fov_x_deg=60.0, width=width,
                         height=height)
    rows = []
    for label, where in SYNTHETIC:
        if where == "infinity":
            light = light_parallel_to_image(cam, 30.0)
        elif where == "corner":
            light = light_toward_pixel(cam, 0.5, 0.5)
        elif where == "off_left":
            light = light_toward_pixel(cam, -0.25, 0.5 * height)
        else:
            light = light_toward_pixel(cam, where[0] * width, where[1] * height)
        rows.append({"kind": "synthetic", "name": label, **geometry_row(describe(cam, light))})
    return rows


def _md_rows(rows):
    out = []
    for r in rows:
        at_inf = r["case"] == "at_infinity"
        ep = "∞" if at_inf else f"({r['epipole_x']:.0f}, {r['epipole_y']:.0f})"
        out.append([r["name"], r["light"], r["case"], ep, r["slices_sinh"], r["slices_uniform"],
                    f"{100 * r['saving']:.1f} %", f"{r['max_px_sinh']:.3f}",
                    f"{r['max_px_uniform']:.3f}", r["ring_pixels"],
                    f"{100 * r['ring_fraction']:.2f} %"])
    return out


HEADER = ["scene", "light", "epipole case", "epipole (px)", "sinh slices", "uniform slices",
          "sinh saving", "max px-to-slice, sinh [px]", "max px-to-slice, uniform [px]",
          "ring pixels (2°)", "ring share"]


def report(suite, synthetic, width, height) -> str:
    on = [r for r in suite if r["case"] == "on_screen"]
    off = [r for r in suite if r["case"] != "on_screen"]
    centre = next(r for r in synthetic if r["name"] == "centre")
    corner = next(r for r in synthetic if r["name"].startswith("corner"))
    near = next(r for r in synthetic if r["name"].startswith("near corner"))

    ring = [r["ring_fraction"] for r in synthetic if r["ring_pixels"]] or [0.0]

    def span(rs, key):
        vals = [r[key] for r in rs]
        if not vals:
            return "-"
        return str(min(vals)) if min(vals) == max(vals) else f"{min(vals)}-{max(vals)}"

    notes = [
        f"- **Centre** ({width}x{height}): sinh {centre['slices_sinh']} vs uniform "
        f"{centre['slices_uniform']}, a saving of {100 * centre['saving']:.1f} % -- "
        f"Baran §8 reports 15 %.",
        f"- **Near a corner**: {100 * near['saving']:.1f} % at 5 % of the image size from "
        f"the corner, {100 * corner['saving']:.1f} % half a pixel from it -- Baran §8 "
        "reports 'half the number of slices'.",
        f"- **Suite**: on-screen epipoles need {span(on, 'slices_sinh')} sinh slices "
        f"(uniform {span(on, 'slices_uniform')}), off-screen/behind ones "
        f"{span(off, 'slices_sinh')} (uniform {span(off, 'slices_uniform')}).  Baran's "
        "three scenes used 2116-2264 (§10) at 1280x960.  That is not the "
        f"count of an epipole near the centre ({centre['slices_sinh']} here, "
        f"{100 * (1 - 0.15):.0f} % of the {2 * (width + height)}-px perimeter by his own "
        "15 %), but it is what an on-screen epipole near a corner needs "
        f"({corner['slices_sinh']} at the corner, {near['slices_sinh']} at 5 % in) or an "
        "off-screen epipole close to the image (spot_room, terrain, 'just off the left "
        "edge' above); his SIBENIK has its epipole on screen (§10.1), so presumably "
        "away from the centre.  His §10.2 figure (700-800 sinh slices for the density "
        "of 1024 uniform ones, a 22-32 % saving) is in the range of our off-screen "
        "savings.",
        "- **Half-pixel bound**: every row keeps the largest pixel-to-slice distance "
        "at or below 0.5 px for both distributions.  sinh sits at 0.500 (its slices "
        "are exactly 1 px apart, perpendicular to themselves, where they leave the "
        "image); uniform falls below 0.5 px when its slices leave the image obliquely "
        "(their perpendicular spacing is 1 px times the cosine of the crossing "
        "angle): that slack is what sinh saves.",
        "- **Ring**: the 2° ring around an on-screen epipole covers "
        + ", ".join(f"{r['name']} {100 * r['ring_fraction']:.2f} %" for r in on)
        + " of the image; at the synthetic positions with pixels in it "
        + "-".join(f"{100 * f:.2f}" for f in (min(ring), max(ring)))
        + " % (Baran §10.1: "
        "'≈2.5 % of total screen area' for his 'about two degrees' ring, i.e. a "
        "narrower field of view or a wider ring than our 2° at 60°).",
    ]
    paper = c.markdown_table(["Baran et al. 2010", "value", "where"],
                             [[p["what"], p["value"], p["where"]] for p in PAPER])
    return "\n\n".join([
        f"# Epipolar slice counts at {width}x{height} (rectify issue, point 4)",
        "`episcatter epipolar SCENE -D res_x=... -D res_y=...` for every suite scene "
        "(`rectify.describe`): Baran's sinh distribution (§8, Eq. 5) against uniform "
        "1-px spacing along the edges the slices leave through; both keep every pixel "
        "centre within 0.5 px of a slice line.",
        "## Suite scenes", c.markdown_table(HEADER, _md_rows(suite)),
        "## Synthetic epipole positions (directional light, 60° camera)",
        c.markdown_table(HEADER, _md_rows(synthetic)),
        "## Baran's figures", paper + f"\n\n(line numbers of `{PAPER_FILE}`)",
        "## What the numbers say", "\n".join(notes)])


def main(argv=None):
    import scenes

    p = c.base_parser(__doc__, list(scenes.SUITE), ["nave_offscreen", "nave_onscreen"])
    p.add_argument("--width", type=int, default=None, help="image width (default 1280)")
    p.add_argument("--height", type=int, default=None, help="image height (default 960)")
    args = p.parse_args(argv)
    width = args.width or (160 if args.quick else 1280)
    height = args.height or (120 if args.quick else 960)
    out = c.output_dir(NAME, args.out, args.quick)
    suite = suite_rows(c.scenes_of(args), width, height)
    synthetic = synthetic_rows(width, height)
    text = report(suite, synthetic, width, height)
    print(text)
    settings = {"name": NAME, "width": width, "height": height, "ring_deg": 2.0,
                "uniform": "1 px spacing along the exit edges, corners included",
                "synthetic_camera": "yaw 20°, pitch -10°, 60° horizontal fov",
                "paper": PAPER, "paper_file": PAPER_FILE, "quick": args.quick}
    rows = suite + synthetic
    c.write_csv(out / "slice_counts.csv", rows)
    c.write_json(out / "slice_counts.json", settings, rows)
    c.write_text(out / "table.md", text)
    return rows


if __name__ == "__main__":
    main()
