"""What each light costs: a scene with k lights against one camera capture
plus the scattering of each of its lights alone.

Single scattering is linear in the light, so a k-light render is one camera
capture (its surface lighting sums the k lights) plus each light's
scattering; this checks that the sum adds nothing else:
``total(k) <= capture(k) + sum_i scattering(light i alone) + 10 %``.

From a scene with several lights (default: the suite's ``six_spots``),
variants are written with its first k lights (``--counts``, default 1 2 6)
and with each light alone; every method renders each variant once as a
warm-up, then ``--repeats`` times (median of the end-to-end time and of each
stage of ``RenderResult.timings``), all in one process.

Writes ``results/light_cost/``: ``runs.csv``, ``runs.json``, ``table.md``.
``python -m experiments.light_cost [--scene six_spots] [--size 640x480]
[--counts 1 2 6] [--methods ...] [--quick]``.
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
import xml.etree.ElementTree as ET

from . import common as c


NAME = "light_cost"
METHODS = ["raymarch", "epipolar_tree", "fourier_filter", "minmax_epipolar"]
#: the sum may exceed capture + the lights' own scattering by this fraction
SLACK = 0.10


def variant_text(text: str, keep) -> str:
    """The scene XML ``text`` with only the emitters at positions ``keep``."""
    root = ET.fromstring(text)
    emitters = [e for e in root if e.tag == "emitter"]
    for i, e in enumerate(emitters):
        if i not in keep:
            root.remove(e)
    return ET.tostring(root, encoding="unicode")


def write_variants(scene_path: str, counts, folder: str) -> tuple[dict, dict, int]:
    """({k: path} of the first-k-lights scenes, {i: path} of each light
    alone, the scene's light count), written next to each other in
    ``folder`` (relative asset paths resolve through the scene's folder)."""
    with open(scene_path) as f:
        text = f.read()
    n = sum(1 for e in ET.fromstring(text) if e.tag == "emitter")
    if max(counts) > n:
        raise SystemExit(f"--counts {max(counts)}: {scene_path} has {n} lights")

    def write(name, keep):
        path = os.path.join(folder, f"{name}.xml")
        with open(path, "w") as f:
            f.write(variant_text(text, set(keep)))
        return path
    return ({k: write(f"first_{k}", range(k)) for k in counts},
            {i: write(f"light_{i}", [i]) for i in range(max(counts))}, n)


def timed(scene, integ, repeats: int) -> dict:
    from episcatter.bench import render_with_stages

    render_with_stages(scene, integ, spp=1)                     # warm-up
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        _, stages = render_with_stages(scene, integ, spp=1)
        runs.append((time.perf_counter() - t0, stages))
    return {"time_s": statistics.median(r[0] for r in runs),
            "capture_s": statistics.median(r[1]["capture"] for r in runs),
            "scattering_s": statistics.median(r[1]["scattering"] for r in runs)}


def measure(scene_path: str, size, counts, methods, repeats: int) -> list[dict]:
    import mitsuba as mi

    defines = c.resolution(*size)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        firsts, alone, n = write_variants(scene_path, counts, folder)
        mi.Thread.thread().file_resolver().prepend(os.path.dirname(os.path.abspath(scene_path)))
        for method in methods:
            integ = c.build(method, {})
            single = {i: timed(c.load(p, defines), integ, repeats) for i, p in alone.items()}
            for k, path in firsts.items():
                t = timed(c.load(path, defines), integ, repeats)
                own = sum(single[i]["scattering_s"] for i in range(k))
                bound = t["capture_s"] + own
                rows.append({"method": method, "lights": k, **t,
                             "single_scattering_s": [single[i]["scattering_s"] for i in range(k)],
                             "capture_1_s": single[0]["capture_s"],
                             "bound_s": bound, "over_bound": t["time_s"] / bound,
                             "within": t["time_s"] <= (1 + SLACK) * bound})
                r = rows[-1]
                print(f"{method} k={k}: total {r['time_s']:.3f} s, capture {r['capture_s']:.3f} s, "
                      f"scattering {r['scattering_s']:.3f} s; capture + lights alone "
                      f"{bound:.3f} s -> {r['over_bound']:.2f}x", flush=True)
    return rows


def report(rows, settings) -> str:
    head = (f"# Cost of k lights, {settings['scene']} at {settings['width']}x{settings['height']}, "
            f"defaults, 1 spp (median of {settings['repeats']})\n\n"
            "total = end-to-end time of the k-light scene; bound = its camera capture (the "
            "surface lighting sums the k lights) + each of its lights' scattering measured on "
            f"a scene with that light alone; the target: total <= (1 + {SLACK:g}) x bound.\n\n")
    table = [[r["method"], r["lights"], f"{r['time_s']:.3f}", f"{r['capture_s']:.3f}",
              f"{r['capture_1_s']:.3f}", f"{r['scattering_s']:.3f}",
              f"{sum(r['single_scattering_s']):.3f}", f"{r['bound_s']:.3f}",
              f"{r['over_bound']:.2f}", "yes" if r["within"] else "NO"] for r in rows]
    return head + c.markdown_table(
        ["method", "k", "total [s]", "capture [s]", "capture, 1 light [s]", "scattering [s]",
         "sum of lights alone [s]", "bound [s]", "total / bound", "within"], table)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="six_spots")
    p.add_argument("--size", default="640x480", metavar="WxH")
    p.add_argument("--counts", type=int, nargs="+", default=[1, 2, 6])
    p.add_argument("--methods", nargs="+", default=METHODS)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--quick", action="store_true", help="48x36, counts 1 2, one repeat")
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    size = (48, 36) if args.quick else tuple(int(x) for x in args.size.split("x"))
    counts = [1, 2] if args.quick else args.counts
    repeats = 1 if args.quick else args.repeats
    with c.limit_blas_threads(1):
        rows = measure(c.scene_file(args.scene), size, counts, args.methods, repeats)
    settings = {"name": NAME, "scene": args.scene, "width": size[0], "height": size[1],
                "counts": counts, "methods": args.methods, "repeats": repeats, "slack": SLACK}
    out = c.output_dir(NAME, args.out, args.quick)
    text = report(rows, settings)
    c.write_csv(out / "runs.csv", rows)
    c.write_json(out / "runs.json", settings, rows)
    c.write_text(out / "table.md", text)
    print(text)
    return rows


if __name__ == "__main__":
    main()
