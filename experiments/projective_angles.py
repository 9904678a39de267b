"""``fourier_filter``: Klehm's projective rectification against the epipolar
slices, as the epipole moves away from the image (Klehm et al. 2014, §4.2).

Klehm §4.2 switches to a projective rectification "depending on the
distance of the epipole to the screen border".  Here the camera of the
``sun_ahead`` stress scene (:func:`scenes.fourier_stress.sun_beside`: open
ground, posts and a grate, σt = 0.05, HG 0.3) is turned ``yaw`` degrees
away from the sun, so the epipole lies left of the image; for each yaw:

- the smallest angle between a view ray of the image and the camera-light
  axis (:func:`rectify.projective.frustum_axis_angle`, the quantity
  ``projective_min_angle`` thresholds);
- ``fourier_filter`` with ``rectification`` = ``epipolar`` / ``projective``
  × ``weights`` = ``reference_ray`` / ``exact`` (the Fourier filter; its
  defaults otherwise): rows used (``RenderResult.stats["rows"]``), relMSE
  (scale-free, ε = 1e-2·mean(ref)², DESIGN §2), mean ratio, FLIP, end-to-end
  and scattering times (median of ``repeats`` warm runs, interleaved in one
  process, OpenBLAS on one thread);
- **pixel centres**: 1 spp against ``raymarch visibility=exact`` (2048
  steps) at the same pixel centres (:func:`experiments.common.exact_reference`,
  cached).

``projective`` is refused closer than 5° to the axis (the map degenerates):
those rows say so.  Writes ``results/projective_angles/``: ``runs.csv``,
``runs.json``, ``table.md`` and the generated scenes under ``scenes/``.
``python -m experiments.projective_angles [--quick] [--yaws ...]``.
"""
from __future__ import annotations

import sys
from pathlib import Path

from . import common as c

NAME = "projective_angles"
#: camera yaw away from the sun [deg]; the image spans ±30° horizontally
YAWS = [38.0, 43.0, 50.0, 62.0, 74.0, 88.0, 100.0]
QUICK_YAWS = [40.0, 70.0]
RECTIFICATIONS = ["epipolar", "projective"]
WEIGHTS = ["reference_ray", "exact"]


def settings_for(quick: bool) -> dict:
    if quick:
        return {"width": 40, "height": 30, "reference_steps": 256, "yaws": QUICK_YAWS}
    return {"width": 320, "height": 240, "reference_steps": c.REFERENCE_STEPS, "yaws": YAWS}


def write_scene(folder: Path, yaw: float) -> Path:
    """The ``sun_beside`` scene turned ``yaw`` degrees, as an XML file."""
    from scenes.fourier_stress import sun_beside

    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"sun_beside_{yaw:g}.xml"
    path.write_text(sun_beside(False, yaw).to_string())
    return path


def axis_angle(scene) -> float:
    """Smallest angle [deg] between a view ray and the camera-light axis."""
    from integrators.epipolar.frame import epipolar_frame_of
    from integrators.core.scene_params import SceneParams
    from rectify.projective import frustum_axis_angle

    return frustum_axis_angle(epipolar_frame_of(SceneParams.from_scene(scene)))


def rows_used(scene, integrator) -> int:
    """Rows (epipolar slices or projective rows) of one render."""
    return int(integrator.render_layers(scene).stats.get("rows", 0))


def measure_yaw(yaw: float, s: dict, repeats: int, folder: Path) -> list[dict]:
    """Every (rectification, weights) setting at camera yaw ``yaw``."""
    path = str(write_scene(folder, yaw))
    defines = c.resolution(s["width"], s["height"])
    ref, _ = c.exact_reference(path, defines, s["reference_steps"], progress=False)
    scene = c.load(path, defines)
    angle = axis_angle(scene)
    jobs = {(r, w): c.build("fourier_filter", {"rectification": r, "weights": w})
            for r in RECTIFICATIONS for w in WEIGHTS}
    runnable = {}
    rows = []
    for (r, w), integ in jobs.items():
        row = {"yaw_deg": yaw, "axis_angle_deg": angle, "rectification": r, "weights": w}
        try:
            row["rows"] = rows_used(scene, integ)
            runnable[(r, w)] = integ
        except Exception as exc:  # noqa: BLE001 -- a refused setting is a result
            row["status"] = c.describe_error(exc)
        rows.append(row)
    timed = c.time_renders(scene, runnable, repeats=repeats)
    for row in rows:
        t = timed.get((row["rectification"], row["weights"]))
        if t is None:
            continue
        if "error" in t:
            row["status"] = t["error"]
            continue
        row.update(status="ok", time_s=t["time_s"], scattering_s=t["scattering_s"],
                   **c.errors(t["image"], ref, blocks=(1,)))
    return rows


def ratio_rows(rows: list[dict]) -> list[list]:
    """Per yaw: rows and projective / epipolar ratios of relMSE and time."""
    out = []
    for yaw in dict.fromkeys(r["yaw_deg"] for r in rows):
        at = {(r["rectification"], r["weights"]): r for r in rows if r["yaw_deg"] == yaw}
        line = [f"{next(iter(at.values()))['axis_angle_deg']:.1f}°"]
        e, p = at[("epipolar", "reference_ray")], at[("projective", "reference_ray")]
        line.append(f"{p.get('rows', '-')} / {e.get('rows', '-')}" +
                    (f" ({p['rows'] / e['rows']:.2f}×)" if p.get("rows") and e.get("rows")
                     else ""))
        for key in ("relmse_b1", "scattering_s"):
            for w in WEIGHTS:
                e, p = at[("epipolar", w)], at[("projective", w)]
                if p.get("status") != "ok" or e.get("status") != "ok":
                    line.append("refused" if e.get("status") == "ok" else e.get("status", "-"))
                else:
                    line.append(f"{p[key] / e[key]:.2f}× ({c.fmt(p[key])} / {c.fmt(e[key])})")
        out.append(line)
    return out


def report(rows: list[dict], s: dict, repeats: int) -> str:
    head = ["view rays ≥ … from the axis", "rows projective / epipolar",
            "relMSE `reference_ray` proj/epi", "relMSE `exact` proj/epi",
            "scattering `reference_ray` proj/epi", "scattering `exact` proj/epi"]
    detail = [[f"{r['yaw_deg']:g}", f"{r['axis_angle_deg']:.1f}", r["rectification"], r["weights"],
               r.get("rows", "-"), c.fmt(r.get("relmse_b1")), c.fmt(r.get("mean_ratio_b1")),
               c.fmt(r.get("flip_b1")), c.fmt(r.get("scattering_s")), c.fmt(r.get("time_s")),
               r.get("status", "-")] for r in rows]
    return "\n\n".join([
        f"`fourier_filter` projective vs epipolar rectification, sun_beside at "
        f"{s['width']}x{s['height']}, pixel centres (1 spp vs raymarch exact, "
        f"{s['reference_steps']} steps), scale-free relMSE (eps = 1e-2·mean(ref)²), "
        f"median of {repeats} warm runs, load {c.load_average()}",
        c.markdown_table(head, ratio_rows(rows)),
        c.markdown_table(["yaw", "axis angle", "rectification", "weights", "rows", "relMSE",
                          "mean ratio", "FLIP", "scattering s", "total s", "status"], detail)])


def main(argv=None):
    p = c.base_parser(__doc__, [], [])
    p.add_argument("--yaws", nargs="+", type=float, default=None,
                   help=f"camera yaws away from the sun [deg] (default {YAWS})")
    args = p.parse_args(argv)
    s = settings_for(args.quick)
    if args.yaws:
        s["yaws"] = args.yaws
    repeats = c.repeats_of(args)
    out = c.output_dir(NAME, args.out, args.quick)
    from tqdm.auto import tqdm

    rows = []
    for yaw in tqdm(s["yaws"], desc="yaws", disable=args.quick):
        rows += c.scene_rows_checkpointed(out / "checkpoints", f"yaw_{yaw:g}",
                                          {**s, "repeats": repeats}, args.resume,
                                          lambda: measure_yaw(yaw, s, repeats, out / "scenes"))
    text = report(rows, s, repeats)
    print(text)
    c.write_csv(out / "runs.csv", rows)
    c.write_json(out / "runs.json", {"name": NAME, **s, "repeats": repeats, "quick": args.quick,
                                     "reference": c.reference_note(s["reference_steps"])}, rows)
    c.write_text(out / "table.md", text)
    return rows


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
