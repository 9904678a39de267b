"""The talk's performance tables for ``minmax_epipolar`` (Yusov 2013,
"Performance": spot light at 2560×1600, 1366×768 and 1024×768 with the
brute force and the three quality profiles; the directional test at
1280×960 with 1024 slices, 512 samples and a 4096² map).

Per resolution and setting: median time of every stage (``--repeats`` warm
runs after a warm-up, interleaved), the scattering stage (the talk's times
exclude the back-buffer and shadow-map renders: ``paper_ms`` = scattering
minus the ``shadowmap`` stage), the estimated working set (the talk's
"Mem, MB", :func:`experiments.minmax_common.working_set_mb`), and the errors
at pixel centres against the exact working reference (``raymarch
visibility=exact``, ``reference_steps`` segments): scale-free relMSE, mean
ratio, max |error| / peak, FLIP; the talk's milliseconds beside ours.

Brute force: the talk marches every shadow-map texel along every pixel's
view ray (no epipolar sampling, no tree).  Our equivalent is ``raymarch
visibility=shadowmap`` with the talk's map size and ``brute_steps``
segments per pixel (2×2 PCF), the per-pixel shadow-mapped marcher.

The machine is 2 shared cores: ``--scale`` (default 0.25) divides every
resolution (the slice/sample/map counts stay the talk's; the samples per
slice are then capped at about one per pixel by the rescaled exit points);
``--scale 1`` runs the talk's sizes.  Spot scene ``spot_room`` (textured
spot light), directional scene ``nave_offscreen``.

Writes ``results/minmax_performance/``: ``runs.csv``, ``runs.json``,
``table.md``.  ``python -m experiments.minmax_performance [--quick] [--scale S]``.
"""
from __future__ import annotations

import argparse

from . import common as c
from . import minmax_common as mc

NAME = "minmax_performance"
SPOT_SCENE = "spot_room"
DIRECTIONAL_SCENE = "nave_offscreen"
#: the talk's tables: (width, height) -> setting -> (slices, samples, map, ms, MB)
TALK = {
    (2560, 1600): {"brute_force": (None, None, 4096, 91.18, None),
                   "high_quality": (2048, 1024, 4096, 5.986, 88.0),
                   "balanced": (1024, 1024, 2048, 3.269, 44.0),
                   "high_performance": (1024, 512, 1024, 2.267, 18.0)},
    (1366, 768): {"brute_force": (None, None, 2048, 164.0, None),
                  "high_quality": (1024, 1024, 2048, 18.9, 44.0),
                  "balanced": (512, 512, 1024, 8.37, 11.0),
                  "high_performance": (512, 256, 512, 5.38, 4.5)},
    (1024, 768): {"brute_force": (None, None, 2048, 184.79, None),
                  "high_quality": (1024, 1024, 2048, 28.83, 44.0),
                  "balanced": (512, 512, 1024, 12.85, 11.0),
                  "high_performance": (512, 256, 512, 8.85, 4.5)},
}
GPU = {(2560, 1600): "GeForce 680 GTX", (1366, 768): "Quadro 1000M",
       (1024, 768): "Intel HD Graphics (3rd gen)"}
#: the directional test (GeForce 480 GTX): "just above 4 ms"
DIRECTIONAL = {"size": (1280, 960), "slices": 1024, "samples": 512, "map": 4096, "talk_ms": 4.0}


def settings_for(quick: bool) -> dict:
    if quick:
        return {"scale": 0.03, "reference_steps": 64, "brute_steps": 32,
                "sizes": [(1024, 768)], "profiles": ["high_performance"]}
    return {"scale": 0.25, "reference_steps": 512, "brute_steps": 512,
            "sizes": list(TALK), "profiles": ["high_quality", "balanced", "high_performance"]}


def scaled(size, scale):
    return max(8, round(size[0] * scale)), max(6, round(size[1] * scale))


def jobs_for(size, s) -> dict:
    """{label: integrator properties} of one spot-light table."""
    talk = TALK[size]
    jobs = {"brute_force": {"type": "raymarch", "visibility": "shadowmap", "steps": s["brute_steps"],
                            "shadowmap_resolution": talk["brute_force"][2]}}
    for prof in s["profiles"]:
        slices, samples, sm, _, _ = talk[prof]
        jobs[prof] = {"type": "minmax_epipolar", "slices": slices, "samples": samples,
                      "shadowmap_resolution": sm, "light_rays": sm,
                      "small_image_march": False}
    return jobs


def measure(scene_name, size, jobs, talk_rows, s, repeats, progress) -> list[dict]:
    w, h = scaled(size, s["scale"])
    path = c.scene_file(scene_name)
    defines = c.resolution(w, h)
    ref, _ = c.exact_reference(path, defines, s["reference_steps"], progress=progress)
    scene = c.load(path, defines)
    integ = {k: c.build(v["type"], {kk: vv for kk, vv in v.items() if kk != "type"})
             for k, v in jobs.items()}
    timed = c.time_renders(scene, integ, repeats=repeats)
    rows = []
    for label, r in timed.items():
        row = {"scene": scene_name, "talk_size": f"{size[0]}x{size[1]}", "size": f"{w}x{h}",
               "setting": label, "talk_ms": talk_rows.get(label, (None,) * 4)[3],
               "talk_mem_mb": talk_rows.get(label, (None,) * 5)[4], "load": c.load_average()}
        if "error" in r:
            rows.append({**row, "status": r["error"]})
            continue
        st = r["stages"]
        scat = st.get("scattering", float("nan"))
        row.update(status="ok", total_ms=1e3 * r["time_s"], scattering_ms=1e3 * scat,
                   paper_ms=1e3 * (scat - st.get("shadowmap", 0.0)),
                   first_run_ms=1e3 * r["first_run_s"], **mc.stage_ms(st),
                   **mc.quality(r["image"], ref))
        stats = (integ[label].render_layers(scene, spp=1).stats
                 if hasattr(integ[label], "render_layers") else None)
        if stats:
            row.update(working_set_mb=mc.working_set_mb(stats, w, h),
                       integration_samples=stats["integration_samples"],
                       used_samples=stats["used_samples"], fixup_pixels=stats["fixup_pixels"],
                       mean_steps=stats["mean_steps"])
        rows.append(row)
    return rows


def report(rows, s) -> str:
    header = ["scene", "talk size", "ours", "setting", "talk ms", "our paper ms", "total ms",
              "integrate ms", "mem MB (talk)", "relMSE", "mean ratio", "max err/peak", "FLIP",
              "fix-up px", "load"]
    body = []
    for r in rows:
        if r.get("status") != "ok":
            body.append([r["scene"], r["talk_size"], r["size"], r["setting"], r["talk_ms"],
                         r.get("status"), "", "", "", "", "", "", "", "", ""])
            continue
        mem = f"{c.fmt(r.get('working_set_mb'))} ({c.fmt(r.get('talk_mem_mb'))})" \
            if r.get("working_set_mb") else ""
        body.append([r["scene"], r["talk_size"], r["size"], r["setting"], c.fmt(r["talk_ms"]),
                     c.fmt(r["paper_ms"]), c.fmt(r["total_ms"]), c.fmt(r.get("integrate_ms")),
                     mem, c.fmt(r["relmse"]), c.fmt(r["mean_ratio"], 4),
                     c.fmt(r["max_err_over_peak"]), c.fmt(r["flip"]),
                     r.get("fixup_pixels", ""), r["load"][0]])
    notes = [f"Errors: {mc.CONVENTION} ({s['reference_steps']} steps); scale-free relMSE "
             "(DESIGN §2).", "paper ms = scattering stage minus shadow-map build (the talk "
             "excludes its shadow-map render); brute force = raymarch shadowmap "
             f"{s['brute_steps']} steps (see module docstring).",
             f"Resolutions scaled by {s['scale']} (2 shared cores); the talk's GPUs: "
             + ", ".join(f"{k[0]}x{k[1]}: {v}" for k, v in GPU.items()) + "."]
    return c.markdown_table(header, body) + "\n\n" + "\n".join(notes) + "\n"


def talk_size(text: str) -> tuple[int, int]:
    """``"1024x768"`` -> (1024, 768), one of the talk's table sizes."""
    try:
        size = tuple(int(v) for v in text.lower().split("x"))
    except ValueError:
        size = ()
    if size not in TALK:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not one of the talk's sizes: "
            + ", ".join(f"{w}x{h}" for w, h in TALK))
    return size


def add_arguments(p) -> None:
    p.add_argument("--sizes", nargs="+", type=talk_size, default=None,
                   help="talk table sizes to run (default: all), e.g. 1024x768")
    p.add_argument("--no-directional", action="store_true",
                   help="skip the directional test (1280x960, 4096² map)")


def main(argv=None):
    args, s, repeats, out = mc.scaled_run(__doc__, settings_for, NAME, argv, [SPOT_SCENE],
                                          [SPOT_SCENE], add_arguments)
    if args.sizes:
        s["sizes"] = list(args.sizes)
    rows = []
    for size in s["sizes"]:
        rows += measure(SPOT_SCENE, size, jobs_for(size, s), TALK[size], s, repeats,
                        not args.quick)
        print(f"{size}: done (load {c.load_average()})", flush=True)
    d = DIRECTIONAL
    dir_jobs = {"high_quality_directional": {
        "type": "minmax_epipolar", "slices": d["slices"], "samples": d["samples"],
        "light_rays": d["map"], "shadowmap_resolution": d["map"], "small_image_march": False},
        "brute_force": {"type": "raymarch", "visibility": "shadowmap",
                        "steps": s["brute_steps"], "shadowmap_resolution": d["map"]}}
    talk_dir = {"high_quality_directional": (d["slices"], d["samples"], d["map"], d["talk_ms"],
                                             None)}
    if not args.no_directional:
        rows += measure(DIRECTIONAL_SCENE, d["size"], dir_jobs, talk_dir, s, repeats,
                        not args.quick)
    text = report(rows, s)
    print(text)
    settings = {"name": NAME, **s, "repeats": repeats, "conventions": mc.CONVENTION,
                "reference": c.reference_note(s["reference_steps"]), "quick": args.quick}
    mc.write_results(out, settings, rows, text)
    return rows


if __name__ == "__main__":
    main()
