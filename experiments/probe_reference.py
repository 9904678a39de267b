"""Which exact marcher should ``quality="auto"``'s probe measure against?
Per held-out scene (``experiments.error_budget.scene_spec``, kind
``mixed``), on the probe's pixel centres
(:func:`integrators.core.quality_auto.probe_pixels`): the scale-free relMSE
of each candidate reference against ``raymarch visibility=exact
steps=8192 boundary_bisections=12``, and its warm time (median of 3, a
partial render of the probe's pixels, as the probe runs it).

Candidates: plain midpoint steps (512, 4,096: the probe's references
before) and the bisected marcher
(:func:`integrators.core.marching.march_bisected`) at 64/128/256/512/1024
steps; a textured spot light marks its row (its texture varies inside
the lit intervals the bisections find).

Writes ``results/probe_reference/``: ``runs.csv``, ``table.md``.
``python -m experiments.probe_reference [--size 320x240] [--seeds 2000,...]``
(about 3 minutes on 2 cores for the default 12 scenes).
"""
from __future__ import annotations

import statistics
import time
from pathlib import Path

NAME = "probe_reference"
OUT = Path(__file__).resolve().parent.parent / "results" / NAME
#: the held-out scenes (spot shafts, window rooms, point lights, thick
#: fog, textured spots)
SEEDS = (2000, 2001, 2002, 2003, 2004, 2007, 2014, 2016, 2017, 2018, 2020, 2021, 2028)
TRUTH = {"steps": 8192, "boundary_bisections": 12}
CANDIDATES = {"plain 512": {"steps": 512}, "plain 4096": {"steps": 4096},
              "bisected 64x8": {"steps": 64, "boundary_bisections": 8},
              "bisected 128x8": {"steps": 128, "boundary_bisections": 8},
              "bisected 256x8": {"steps": 256, "boundary_bisections": 8},
              "bisected 512x6": {"steps": 512, "boundary_bisections": 6},
              "bisected 1024x6": {"steps": 1024, "boundary_bisections": 6}}


def probe_values(scene, props: dict, mask, pixels, repeats: int):
    """(values on the probe pixels, median warm seconds) of the exact
    marcher with ``props``, a partial render of the probe's pixels."""
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    integ = mi.load_dict({"type": "raymarch", "visibility": "exact", **props})
    res = integ.render_layers(scene, spp=1, samples=mask)      # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = integ.render_layers(scene, spp=1, samples=mask)
        dr.eval(res["full"])
        dr.sync_thread()
        times.append(time.perf_counter() - t0)
    img = np.asarray(res["full"], np.float64)
    return img.reshape(-1, img.shape[-1])[pixels], statistics.median(times)


def run(seeds, width: int, height: int, repeats: int = 3) -> list[dict]:
    import numpy as np

    from experiments.error_budget import scene_spec
    from integrators.core.quality_auto import probe_pixels, subset_relmse
    from integrators.core.scene_params import SceneParams

    pixels = probe_pixels(width, height)
    mask = np.zeros(width * height, bool)
    mask[pixels] = True
    rows = []
    for seed in seeds:
        scene = scene_spec(seed, "mixed").at_resolution(width, height).load()
        params = SceneParams.from_scene(scene)
        textured = any(light.textured for light in params.lights)
        kinds = "+".join(light.kind for light in params.lights)
        truth, _ = probe_values(scene, TRUTH, mask, pixels, 1)
        for name, props in CANDIDATES.items():
            values, t = probe_values(scene, props, mask, pixels, repeats)
            rows.append({"seed": seed, "lights": kinds, "textured": textured,
                         "reference": name, "relmse": subset_relmse(values, truth),
                         "time_s": t})
        print(f"seed {seed} ({kinds}{', textured' if textured else ''}): "
              + ", ".join(f"{r['reference']} {r['relmse']:.1e} {r['time_s']:.3f}s"
                          for r in rows if r["seed"] == seed), flush=True)
    return rows


def table(rows, width: int, height: int) -> str:
    names = list(CANDIDATES)
    lines = [f"# Probe references at {width}x{height}", "",
             "relMSE on the probe's pixel centres against "
             f"`raymarch visibility=exact steps={TRUTH['steps']} "
             f"boundary_bisections={TRUTH['boundary_bisections']}`; time: median of 3 "
             "warm partial renders of those pixels [s].", "",
             "| seed | lights | " + " | ".join(names) + " |",
             "|---|---|" + "---|" * len(names)]
    for seed in dict.fromkeys(r["seed"] for r in rows):
        sel = {r["reference"]: r for r in rows if r["seed"] == seed}
        first = next(iter(sel.values()))
        lights = first["lights"] + (" (textured)" if first["textured"] else "")
        lines.append(f"| {seed} | {lights} | " + " | ".join(
            f"{sel[n]['relmse']:.1e} ({sel[n]['time_s']:.3f})" for n in names) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    from . import common as c

    _, out = c.held_out_main(__doc__, SEEDS, OUT, run, table, argv)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
