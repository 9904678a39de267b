"""``fourier_filter`` with spot lights against ``epipolar_tree``: accuracy,
warm time and peak memory at the defaults and with more Fourier
coefficients.

Spot lights take Klehm 2014's filter under the default ``visibility=exact_directional`` (their
kernel per texel and query makes the direct sum many times the filter's
cost), so the truncated series' ringing is the error a user sees.  Per
scene (``spot_room``, ``spot_columns``), at pixel centres against the exact
working reference (cached): scale-free relMSE, mean ratio, the warm median
of ``--repeats`` interleaved renders, and the peak resident memory of one
process that renders the scene twice with that setting alone (a child
process per setting: the peak of a process is not reset).

Writes ``results/fourier_spot/``: ``runs.csv``, ``runs.json``, ``table.md``.
``python -m experiments.fourier_spot [--size 320x240] [--quick]``.
"""
from __future__ import annotations

import json
import subprocess
import sys

from . import common as c
from . import minmax_common as mc

NAME = "fourier_spot"
SCENES = ["spot_room", "spot_columns"]
QUICK_SCENES = ["spot_columns"]
SETTINGS = {"epipolar_tree": ("epipolar_tree", {}),
            "fourier_filter": ("fourier_filter", {}),
            "fourier_filter M=64": ("fourier_filter", {"coefficients": 64}),
            "fourier_filter M=128": ("fourier_filter", {"coefficients": 128})}

_PEAK = """
import json, sys
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
import integrators
path, w, h, kind, props = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], json.loads(sys.argv[5])
scene = mi.load_file(path, res_x=w, res_y=h, spp=1)
def hwm():        # this process's peak resident set (MB): VmHWM (ru_maxrss keeps the parent's)
    line = next(l for l in open("/proc/self/status") if l.startswith("VmHWM"))
    return int(line.split()[1]) / 1024
base = hwm()
integ = mi.load_dict({"type": kind, "output": "scattering", **props})
for _ in range(2):
    mi.render(scene, integrator=integ, spp=1).numpy()
print(json.dumps({"base_mb": base, "peak_mb": hwm()}))
"""


def settings_for(quick: bool) -> dict:
    if quick:
        return {"width": 48, "height": 36, "reference_steps": 64}
    return {"width": 320, "height": 240, "reference_steps": c.REFERENCE_STEPS}


def peak_memory(name: str, s: dict, kind: str, props: dict) -> dict:
    """Peak resident memory (MB) of a child process rendering twice."""
    out = subprocess.run([sys.executable, "-c", _PEAK, c.scene_file(name), str(s["width"]),
                          str(s["height"]),
                          kind, json.dumps(props)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def measure_scene(name: str, s: dict, repeats: int, progress: bool) -> list[dict]:
    ref, timed = c.timed_scattering(name, s, SETTINGS, repeats, progress)
    rows = []
    for label, r in timed.items():
        kind, props = SETTINGS[label]
        row = {"scene": name, "setting": label, "width": s["width"], "height": s["height"]}
        if "error" in r:
            rows.append({**row, "status": r["error"]})
            continue
        q = mc.quality(r["image"], ref)
        mem = peak_memory(name, s, kind, props)
        rows.append({**row, "status": "ok", "warm_s": r["time_s"], "relmse": q["relmse"],
                     "mean_ratio": q["mean_ratio"], "peak_mb": mem["peak_mb"],
                     "base_mb": mem["base_mb"]})
    return rows


def report(rows: list[dict], s: dict, repeats: int) -> str:
    tree = {r["scene"]: r for r in rows if r["setting"] == "epipolar_tree"}
    table = []
    for r in rows:
        t = tree.get(r["scene"], {})
        table.append([r["scene"], r["setting"], c.fmt(r.get("relmse")),
                      c.fmt(r.get("relmse", float("nan")) / t["relmse"]) if t.get("relmse")
                      else "-", c.fmt(r.get("mean_ratio"), 4), c.fmt(r.get("warm_s")),
                      c.fmt(r.get("warm_s", float("nan")) / t["warm_s"]) if t.get("warm_s")
                      else "-", c.fmt(r.get("peak_mb"), 4),
                      c.fmt(r.get("peak_mb", float("nan")) / t["peak_mb"]) if t.get("peak_mb")
                      else "-"])
    head = (f"# fourier_filter with spot lights against epipolar_tree, "
            f"{s['width']}x{s['height']}\n\n{c.reference_note(s['reference_steps'])}.  Warm: "
            f"median of {repeats} interleaved renders (s); peak: resident memory of a process "
            "that loads the scene and renders it twice (MB).\n\n")
    return head + c.markdown_table(
        ["scene", "setting", "relMSE", "x tree", "mean", "warm s", "x tree", "peak MB",
         "x tree"], table)


def main(argv=None) -> list[dict]:
    return c.run_table_experiment(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
