"""Speed of ``minmax_epipolar`` at equal error against ``raymarch`` (shadow
map) and ``epipolar_tree`` (issue 14, point 5; the talk: high quality
"91 → 6 ms", 15× over its brute force).

Per scene: ``raymarch visibility=shadowmap`` (2048² map) sweeps ``steps``;
``minmax_epipolar`` runs a few settings (its time/error curve: defaults,
fewer light rays, a sparser initial step, the talk's high-performance
profile); ``epipolar_tree`` its defaults.  For every
minmax setting, each baseline's time at the same scale-free relMSE is
interpolated log-log on the baseline's curve
(:func:`experiments.tree_speedup.equal_error_time`: ``=`` when bracketed,
``>=``/``<=`` bounds otherwise); speedup = that time / minmax's.  Times:
the scattering stage, raymarch's shadow-map build taken out (the papers'
convention; minmax's traced blockers stay in, conservative), medians of
``--repeats`` warm runs, interleaved (marcher runs of ``long_steps`` steps
or more, tens of seconds each, skip the warm-up: compilation is negligible
there).  Errors at pixel centres against the
exact working reference.

The talk's size is 1280×960 (``--scale`` divides it).

Writes ``results/minmax_speedup/``: ``runs.csv``, ``speedup.csv``,
``runs.json``, ``table.md``, ``frontier.png``; rewritten after every scene,
so an interrupted run keeps the scenes it finished.  ``python -m experiments.minmax_speedup [--quick]``.
"""
from __future__ import annotations

from . import common as c
from . import minmax_common as mc
from .tree_speedup import equal_error_time

NAME = "minmax_speedup"
SCENES = ["nave_offscreen", "point_fog", "nave_onscreen", "spot_room", "grove"]
QUICK_SCENES = ["nave_offscreen"]
TARGET = 10.0


#: minmax_epipolar settings of its time/error curve (label -> properties)
MINMAX = {"minmax defaults": {},
          "minmax light_rays=1024": {"light_rays": 1024},
          "minmax initial_step=32 light_rays=512": {"initial_step": 32, "light_rays": 512},
          "minmax high_performance": {"profile": "high_performance"}}


def settings_for(quick: bool) -> dict:
    if quick:
        return {"scale": 0.04, "reference_steps": 64, "steps": [8, 32], "long_steps": 1 << 30,
                "minmax": ["minmax defaults", "minmax high_performance"]}
    return {"scale": 1.0, "reference_steps": 2048, "steps": [16, 64, 256, 512],
            "long_steps": 256, "minmax": list(MINMAX)}


def jobs(s) -> dict:
    out = {f"raymarch steps={k}": ("raymarch", {"steps": k, "shadowmap_resolution": 2048})
           for k in s["steps"]}
    out["epipolar_tree"] = ("epipolar_tree", {})
    for label in s["minmax"]:
        out[label] = ("minmax_epipolar", MINMAX[label])
    return out


def is_long(label: str, s) -> bool:
    return label.startswith("raymarch") and int(label.split("=")[1]) >= s["long_steps"]


def measure_scene(name, s, repeats, progress) -> list[dict]:
    w, h = round(1280 * s["scale"]), round(960 * s["scale"])
    path = c.scene_file(name)
    defines = c.resolution(w, h)
    ref, _ = c.exact_reference(path, defines, s["reference_steps"], progress=progress)
    scene = c.load(path, defines)
    spec = jobs(s)
    integ = {k: c.build(kind, props) for k, (kind, props) in spec.items()}
    short = {k: v for k, v in integ.items() if not is_long(k, s)}
    long_ = {k: v for k, v in integ.items() if is_long(k, s)}
    timed = c.time_renders(scene, short, repeats=repeats)
    if long_:
        timed.update(c.time_renders(scene, long_, repeats=repeats, warm_up=False))
    rows = []
    for label, r in timed.items():
        row = {"scene": name, "size": f"{w}x{h}", "setting": label, "load": c.load_average()}
        if "error" in r:
            rows.append({**row, "status": r["error"]})
            continue
        st = r["stages"]
        row.update(status="ok", paper_s=st["scattering"] - st.get("shadowmap", 0.0),
                   total_s=r["time_s"], **mc.quality(r["image"], ref))
        if label.startswith("minmax"):
            row.update(mc.stage_ms(st))
        rows.append(row)
    return rows


def speedups(rows) -> list[dict]:
    out = []
    for scene in sorted({r["scene"] for r in rows}):
        ok = [r for r in rows if r["scene"] == scene and r.get("status") == "ok"]
        march = [(r["paper_s"], r["relmse"]) for r in ok if r["setting"].startswith("raymarch")]
        tree = [(r["paper_s"], r["relmse"]) for r in ok if r["setting"] == "epipolar_tree"]
        for r in ok:
            if not r["setting"].startswith("minmax"):
                continue
            t_m, b_m = equal_error_time(march, r["relmse"])
            row = {"scene": scene, "setting": r["setting"], "relmse": r["relmse"],
                   "minmax_s": r["paper_s"], "raymarch_s": t_m, "raymarch_bound": b_m,
                   "speedup_vs_raymarch": t_m / r["paper_s"], "target": TARGET}
            if tree:
                row.update(tree_s=tree[0][0], tree_relmse=tree[0][1],
                           time_ratio_vs_tree=tree[0][0] / r["paper_s"])
            out.append(row)
    return out


def report(rows, summary, s, repeats) -> str:
    runs = c.markdown_table(
        ["scene", "size", "setting", "paper s", "total s", "relMSE", "mean ratio",
         "max err/peak", "FLIP", "load"],
        [[r["scene"], r["size"], r["setting"], c.fmt(r.get("paper_s")), c.fmt(r.get("total_s")),
          c.fmt(r.get("relmse")), c.fmt(r.get("mean_ratio"), 4), c.fmt(r.get("max_err_over_peak")),
          c.fmt(r.get("flip")), r["load"][0]] for r in rows])
    prefix = {"=": "", ">=": ">= ", "<=": "<= "}
    sp = c.markdown_table(
        ["scene", "minmax setting", "relMSE", "minmax s", "raymarch s at equal error",
         "speedup vs raymarch", "epipolar_tree s (its relMSE)", "tree s / minmax s"],
        [[r["scene"], r["setting"], c.fmt(r["relmse"]), c.fmt(r["minmax_s"]),
          c.fmt(r["raymarch_s"]), prefix.get(r["raymarch_bound"], "? ")
          + c.fmt(r["speedup_vs_raymarch"]) + "x",
          f"{c.fmt(r.get('tree_s'))} ({c.fmt(r.get('tree_relmse'))})",
          c.fmt(r.get("time_ratio_vs_tree"))] for r in summary])
    return (runs + "\n\n" + sp + f"\n\nTimes: scattering stage minus raymarch's shadow-map "
            f"build, medians of {repeats} warm runs; errors: {mc.CONVENTION} "
            f"({s['reference_steps']} steps), scale-free relMSE. Target >= {TARGET}x vs "
            "raymarch (the talk: 15x over its brute force).\n")


def plot(path, rows) -> None:
    """Per scene: relMSE against scattering time, the marcher's sweep as a
    line, each minmax setting and epipolar_tree as points."""
    ok = [r for r in rows if r.get("status") == "ok"]
    scenes = sorted({r["scene"] for r in ok})
    if not scenes:
        return
    fig, panels = c.scene_grid(scenes, 3, 3.4)
    for ax, scene in panels:
        mine = [r for r in ok if r["scene"] == scene]
        march = [r for r in mine if r["setting"].startswith("raymarch")]
        ax.plot([r["paper_s"] for r in march], [r["relmse"] for r in march], "o-",
                label="raymarch (shadow map) steps")
        for r in mine:
            if not r["setting"].startswith("raymarch"):
                ax.plot([r["paper_s"]], [r["relmse"]], "s" if "minmax" in r["setting"] else "^",
                        label=r["setting"])
        c.style_loglog(ax, f"{scene} ({mine[0]['size']})", "scattering time [s]",
                       "scale-free relMSE (pixel centres)")
    c.savefig(fig, path)


def main(argv=None):
    args, s, repeats, out = mc.scaled_run(__doc__, settings_for, NAME, argv, SCENES,
                                          QUICK_SCENES)
    rows, summary = [], []
    for name in c.scenes_of(args):
        rows += measure_scene(name, s, repeats, not args.quick)
        print(f"{name}: done (load {c.load_average()})", flush=True)
        summary = speedups(rows)
        text = report(rows, summary, s, repeats)
        mc.write_results(out, {"name": NAME, **s, "repeats": repeats, "quick": args.quick},
                         rows, text, speedup=summary)
        plot(out / "frontier.png", rows)
    print(text)
    return rows, summary


if __name__ == "__main__":
    main()
