"""JIT kernels one warm frame launches, per suite scene and integrator at
its defaults: what each frame costs in launches and host round trips on a
GPU, where a launch (and the synchronisation around a read-back) costs more
than the arithmetic of a small kernel.

Per scene and method: a first render (compiles or loads the kernels), then
one more render inside :func:`episcatter.kernels.kernel_log`: JIT kernels
launched, and of them distinct (by source hash: the kernels an empty cache
would compile).

Per method, also the source lines that launched the most kernels over
the scenes measured (:func:`episcatter.kernels.launch_sites`, a second
warm render under a line tracer): where the next launch to remove is.

Writes ``results/launches/``: ``runs.csv``, ``runs.json``, ``table.md``
(with the launch sites).
``python -m experiments.launches [--size 640x480] [--scenes ...] [--quick]``;
``python -m experiments.launches --trace SCENE METHOD [WxH]`` prints one
warm frame's kernels in launch order, each with its source line and lanes.
"""
from __future__ import annotations

import sys

from . import common as c

NAME = "launches"
SCENES = ["beam", "grove", "hall", "nave_offscreen", "nave_onscreen", "point_fog", "spot_room",
          "sun_ahead", "sun_behind", "sun_room", "terrain"]
QUICK_SCENES = ["point_fog"]
METHODS = ["raymarch", "epipolar_tree", "fourier_filter", "minmax_epipolar"]
#: launch sites listed per method
SITES = 15


def settings_for(quick: bool) -> dict:
    return {"width": 48, "height": 36} if quick else {"width": 640, "height": 480}


def measure_scene(name: str, s: dict, repeats: int, progress: bool) -> list[dict]:
    import drjit as dr
    import mitsuba as mi

    from episcatter.kernels import kernel_log, launch_sites

    scene = c.load(c.scene_file(name), c.resolution(s["width"], s["height"]))
    rows = []
    for kind in METHODS:
        integ = c.build(kind, {})
        dr.eval(mi.render(scene, integrator=integ, spp=1))
        with kernel_log() as log:
            dr.eval(mi.render(scene, integrator=integ, spp=1))
        with launch_sites() as sites:
            dr.eval(mi.render(scene, integrator=integ, spp=1))
        rows.append({"scene": name, "method": kind, "width": s["width"], "height": s["height"],
                     "launched": log.launched, "compiled": log.compiled,
                     "distinct": len({k.get("hash") for k in log.entries}),
                     "sites": dict(sites)})
    return rows


def report(rows: list[dict], s: dict, repeats: int) -> str:
    by = {(r["scene"], r["method"]): r for r in rows}
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    table = [[name] + [f"{by[name, m]['launched']} ({by[name, m]['distinct']})" for m in METHODS]
             for name in scenes]
    head = (f"# JIT kernels launched per warm frame, {s['width']}x{s['height']}\n\n"
            "Each cell: launched (distinct sources).  One render after a first one, at the "
            "integrator's defaults, 1 sample per pixel.\n\n")
    out = head + c.markdown_table(["scene"] + METHODS, table)
    for m in METHODS:
        total = {}
        for r in rows:
            if r["method"] == m:
                for site, n in r.get("sites", {}).items():
                    total[site] = total.get(site, 0) + n
        top = sorted(total.items(), key=lambda kv: -kv[1])[:SITES]
        out += (f"\n\n## `{m}`: the {len(top)} source lines launching the most kernels "
                f"(summed over the {len(scenes)} scenes)\n\n"
                + c.markdown_table(["launches", "line"], [[n, f"`{site}`"] for site, n in top]))
    return out


def trace(scene_name: str, method: str, size=(640, 480)) -> list:
    """(source line, lanes) of every kernel one warm frame of ``method`` on
    suite scene ``scene_name`` launches, in launch order
    (:func:`episcatter.kernels.launch_sites`' ``sequence``)."""
    import drjit as dr
    import mitsuba as mi

    from episcatter.kernels import launch_sites

    scene = c.load(c.scene_file(scene_name), c.resolution(*size))
    integ = c.build(method, {})
    dr.eval(mi.render(scene, integrator=integ, spp=1))
    sequence = []
    with launch_sites(sequence=sequence):
        dr.eval(mi.render(scene, integrator=integ, spp=1))
    return sequence


def main(argv=None) -> list[dict]:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--trace"]:
        if len(argv) < 3:
            raise SystemExit("usage: python -m experiments.launches --trace SCENE METHOD [WxH]")
        size = tuple(int(v) for v in argv[3].split("x")) if len(argv) > 3 else (640, 480)
        sequence = trace(argv[1], argv[2], size)
        for i, (site, lanes) in enumerate(sequence, 1):
            print(f"{i:4d} {lanes:>10} {site}")
        return []
    return c.run_table_experiment(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
