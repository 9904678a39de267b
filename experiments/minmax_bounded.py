"""``minmax_epipolar`` against ``epipolar_tree`` at their defaults on the
suite: is Yusov 2013's method bounded wherever Baran 2010's is?

Per scene, at pixel centres (1 sample per pixel) against the exact working
reference (``raymarch visibility=exact``, cached): scale-free relMSE, mean
ratio and largest pixel error over the reference's peak of each method at
its defaults, and its time -- the first render in this process (kernels
compiled or read from Dr.Jit's cache) and the warm median of ``--repeats``
interleaved renders.  The bound: ``minmax_epipolar``'s relMSE within
``RELMSE_FACTOR`` x ``epipolar_tree``'s (or under ``RELMSE_FLOOR``, where
both are far below any visible error) and its mean within ``MEAN_TOL``.

Writes ``results/minmax_bounded/``: ``runs.csv``, ``runs.json``,
``table.md``.  ``python -m experiments.minmax_bounded [--size 1280x960]
[--scenes ...] [--quick]``.
"""
from __future__ import annotations

import sys

from . import common as c
from . import minmax_common as mc

NAME = "minmax_bounded"
SCENES = ["beam", "grove", "hall", "nave_offscreen", "nave_onscreen", "point_fog", "spot_room",
          "sun_ahead", "sun_behind", "sun_room", "terrain"]
QUICK_SCENES = ["beam"]
METHODS = {"epipolar_tree": ("epipolar_tree", {}),
           "minmax_epipolar": ("minmax_epipolar", {})}
#: minmax's relMSE may be at most this factor above the tree's ...
RELMSE_FACTOR = 10.0
#: ... or below this floor (both methods far below any visible error)
RELMSE_FLOOR = 1e-6
#: |mean ratio - 1| bound of minmax
MEAN_TOL = 0.01


def settings_for(quick: bool) -> dict:
    if quick:
        return {"width": 48, "height": 36, "reference_steps": 64}
    return {"width": 1280, "height": 960, "reference_steps": c.REFERENCE_STEPS}


def measure_scene(name: str, s: dict, repeats: int, progress: bool) -> list[dict]:
    """One row per method: errors against the reference and times."""
    ref, timed = c.timed_scattering(name, s, METHODS, repeats, progress)
    rows = []
    for label, r in timed.items():
        row = {"scene": name, "method": label, "width": s["width"], "height": s["height"]}
        if "error" in r:
            rows.append({**row, "status": r["error"]})
            continue
        q = mc.quality(r["image"], ref)
        rows.append({**row, "status": "ok", "first_s": r["first_run_s"], "warm_s": r["time_s"],
                     **{k: q[k] for k in ("relmse", "mean_ratio", "max_err_over_peak",
                                          "nonfinite")}})
    return rows


def bounded(tree: dict, mm: dict) -> bool:
    """minmax's row within the bound of the tree's (module docstring)."""
    if mm.get("status") != "ok" or tree.get("status") != "ok" or mm["nonfinite"]:
        return False
    relmse_ok = mm["relmse"] <= max(RELMSE_FACTOR * tree["relmse"], RELMSE_FLOOR)
    return relmse_ok and abs(mm["mean_ratio"] - 1.0) <= MEAN_TOL


def report(rows: list[dict], s: dict, repeats: int) -> str:
    by = {(r["scene"], r["method"]): r for r in rows}
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    table = []
    for name in scenes:
        t, m = by.get((name, "epipolar_tree"), {}), by.get((name, "minmax_epipolar"), {})
        ok = bounded(t, m)
        ratio = (m.get("relmse", float("nan")) / t["relmse"]
                 if t.get("relmse") else float("nan"))
        table.append([name, c.fmt(t.get("relmse")), c.fmt(m.get("relmse")), c.fmt(ratio),
                      c.fmt(t.get("mean_ratio"), 4), c.fmt(m.get("mean_ratio"), 4),
                      c.fmt(t.get("max_err_over_peak")), c.fmt(m.get("max_err_over_peak")),
                      c.fmt(t.get("warm_s")), c.fmt(m.get("warm_s")),
                      c.fmt(t.get("first_s")), c.fmt(m.get("first_s")),
                      "yes" if ok else "**no**"])
    n_ok = sum(row[-1] == "yes" for row in table)
    head = (f"# minmax_epipolar vs epipolar_tree at their defaults, {s['width']}x{s['height']}\n\n"
            f"{c.reference_note(s['reference_steps'])}.  Times: seconds, first render in this "
            f"process and warm median of {repeats}.  Bounded: minmax relMSE <= "
            f"{RELMSE_FACTOR:g} x tree's (or <= {RELMSE_FLOOR:g}) and |mean - 1| <= "
            f"{MEAN_TOL:g}.  **{n_ok}/{len(table)} bounded.**\n\n")
    return head + c.markdown_table(
        ["scene", "tree relMSE", "minmax relMSE", "ratio", "tree mean", "minmax mean",
         "tree max err/peak", "minmax max err/peak", "tree warm s", "minmax warm s",
         "tree first s", "minmax first s", "bounded"], table)


def main(argv=None) -> list[dict]:
    return c.run_table_experiment(sys.modules[__name__], argv)


if __name__ == "__main__":
    main()
