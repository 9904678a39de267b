"""``fourier_filter`` at its defaults on the suite and the stress scenes (issue 12).

Three measurements, all against the exact working reference
(``raymarch visibility=exact``, :func:`experiments.common.exact_reference`),
**pixel centres** (1 spp, the reference at the same pixel centres), plain
(black-surface) scenes, so the image is the single scattering alone:

1. *accuracy*: every suite scene and every stress scene of
   :mod:`scenes.fourier_stress` at the defaults (``default``) and with
   Klehm's single reference ray per row on the nearest slice (``paper``:
   ``reference_rays=1, slice_interpolation=false, exact_fallback=false,
   trace_ends=false``, what the defaults were before issue 12: the Fourier
   filter, M = 32):
   scale-free relMSE, mean ratio,
   largest pixel error over the reference peak, non-finite pixels, and the
   light on reference-black pixels (reference below 1e-4 of its peak): the
   largest as a fraction of the peak and how many exceed 1e-4 of it.
   Error maps (|test − ref| / peak) of the stress scenes as PNGs.
2. *thickness*: the sun room with σt swept so that σt · (medium-box
   diagonal) runs from 0.01 to 10: the mean ratio of both.
3. *cost* (``--time``): warm end-to-end time of ``paper``, ``before``
   (the nearest slice, the defaults before the slice interpolation) and the
   defaults, median of ``--repeats`` interleaved runs in one process, at
   ``--time-size``, with the stage timings.

Writes ``results/fourier_defaults/``: ``accuracy.csv``, ``thickness.csv``,
``timing.csv``, ``fourier_defaults.json``, ``table.md`` and
``errors_<scene>.png``.
``python -m experiments.fourier_defaults [--quick] [--time] [--repeats N]``.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

import scenes
from episcatter import metrics

# absolute: --before runs this file in another tree's processes (its own ``experiments``)
from experiments import common as c

NAME = "fourier_defaults"
#: label -> fourier_filter properties
MODES = {"default": {}, "paper": {"reference_rays": 1, "slice_interpolation": False,
                                  "exact_fallback": False, "trace_ends": False}}
#: (the default: ``visibility="exact_directional"`` = the exact sum, slice interpolation
#: with the re-march of disagreeing samples; ``paper`` sets a filter
#: property, so ``auto`` takes the Fourier filter, on the nearest slice)
#: the cost table's modes: ``before`` = the defaults before the slice
#: interpolation and re-march (main's: the nearest slice; the exact sum for
#: directional lights, the filter with its reference rays for point/spot)
TIME_MODES = {"paper": MODES["paper"], "before": {"slice_interpolation": False},
              "default": {}}
#: optical thicknesses σt · size of the sun-room sweep
TAUS = (0.01, 0.1, 1.0, 3.0, 10.0)
#: reference-black pixels: reference below this fraction of its peak
BLACK = 1e-4


def settings_for(quick: bool) -> dict:
    if quick:
        return {"width": 48, "height": 36, "taus": [0.1, 3.0], "reference_steps": 256,
                "scenes": ["sun_room", "sun_behind"], "time_size": (64, 48)}
    return {"width": 320, "height": 240, "taus": list(TAUS), "reference_steps": 1024,
            "scenes": scenes.SUITE + scenes.STRESS_SUITE, "time_size": (640, 480)}


def leak(img, ref) -> dict:
    """Light on the reference-black pixels, relative to the reference peak."""
    peak = float(np.max(ref))
    black = np.mean(ref, axis=-1) < BLACK * peak
    lum = np.mean(img, axis=-1)[black]
    return {"black_pixels": int(black.sum()),
            "leak_max": float(lum.max() / peak) if lum.size else 0.0,
            "leak_pixels": int((lum > BLACK * peak).sum())}


def measures(img, ref) -> dict:
    img = np.asarray(img, np.float64)
    peak = float(np.max(ref))
    return {"relmse": metrics.scale_free_relmse(img, ref),
            "mean_ratio": metrics.mean_ratio(img, ref),
            "max_err_over_peak": float(np.max(np.abs(img - ref)) / peak) if peak > 0 else 0.0,
            "nonfinite": int((~np.isfinite(img)).sum()), **leak(img, ref)}


def render(scene, props):
    return c.time_renders(scene, {"x": c.build("fourier_filter", props)}, repeats=1,
                          warm_up=False)["x"]


def error_map(path, name, images: dict, ref) -> None:
    """|test − ref| / peak of each mode beside the reference."""
    plt = c.pyplot()
    peak = float(np.max(ref))
    fig, axes = plt.subplots(1, len(images) + 1, figsize=(3.2 * (len(images) + 1), 2.6))
    axes[0].imshow(np.clip(np.mean(ref, -1) / peak, 0, 1) ** 0.5, cmap="gray")
    axes[0].set_title(f"{name}: reference (sqrt)", fontsize=8)
    for ax, (label, img) in zip(axes[1:], images.items()):
        err = np.mean(np.abs(np.asarray(img) - ref), -1) / peak
        im = ax.imshow(err, cmap="magma", vmin=0.0, vmax=0.05)
        ax.set_title(f"{label}: |err|/peak (max {err.max():.3g})", fontsize=8)
    for ax in axes:
        ax.set_axis_off()
    fig.colorbar(im, ax=axes[1:], fraction=0.03)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def accuracy(s: dict, out, progress: bool) -> list[dict]:
    rows = []
    for name in s["scenes"]:
        scene, ref, _ = c.scene_with_reference(name, s, progress)
        images = {}
        for label, props in MODES.items():
            t = render(scene, props)
            row = {"scene": name, "mode": label, "params": props, "width": s["width"],
                   "height": s["height"], "status": t.get("error", "ok")}
            if "error" not in t:
                images[label] = t["image"]
                row.update(measures(t["image"], ref))
            rows.append(row)
            print(name, label, {k: c.fmt(v) for k, v in row.items() if k not in ("params",)},
                  flush=True)
        if name in scenes.STRESS_SUITE and images:
            error_map(out / f"errors_{name}.png", name, images, ref)
    return rows


def thickness(s: dict, progress: bool) -> list[dict]:
    from integrators.core.scene_params import SceneParams

    path = c.scene_file("sun_room")
    size = SceneParams.from_scene(c.load(path, c.resolution(s["width"], s["height"]))
                                  ).scene_extent
    rows = []
    for tau in s["taus"]:
        sigma_t = tau / size
        scene, ref, _ = c.scene_with_reference("sun_room", s, progress,
                                               sigma_t=f"{sigma_t:.9g}")
        for label, props in MODES.items():
            t = render(scene, props)
            row = {"scene": "sun_room", "tau": tau, "sigma_t": sigma_t, "size_m": size,
                   "mode": label, **(measures(t["image"], ref) if "error" not in t else
                                     {"status": t["error"]})}
            rows.append(row)
            print("tau", tau, label, c.fmt(row.get("mean_ratio")), flush=True)
    return rows


def timing(s: dict, repeats: int, progress: bool) -> list[dict]:
    w, h = s["time_size"]
    rows = []
    for name in [n for n in s["scenes"] if n in scenes.SUITE] or s["scenes"]:
        scene = c.load(c.scene_file(name), c.resolution(w, h))
        loads = [c.load_average()]
        timed = c.time_renders(scene, {m: c.build("fourier_filter", p)
                                       for m, p in TIME_MODES.items()},
                               repeats=repeats, progress=progress)
        loads.append(c.load_average())
        for label in TIME_MODES:
            t = timed[label]
            rows.append({"scene": name, "mode": label, "width": w, "height": h,
                         "time_s": t.get("time_s"), "first_run_s": t.get("first_run_s"),
                         "scattering_s": t.get("scattering_s"), "stages": t.get("stages"),
                         "load": loads})
        print(name, {m: c.fmt(timed[m].get("time_s")) for m in TIME_MODES}, loads, flush=True)
    return rows


def measure_time(name: str, w: int, h: int, repeats: int) -> dict:
    """This process's tree: the defaults' warm median time (end to end and
    scattering) on one suite scene, 1 spp at pixel centres."""
    scene = c.load(c.scene_file(name), c.resolution(w, h))
    t = c.time_renders(scene, {"default": c.build("fourier_filter", {})},
                       repeats=repeats)["default"]
    return {"scene": name, "time_s": t["time_s"], "scattering_s": t["scattering_s"],
            "first_run_s": t["first_run_s"], "stages": t["stages"], "load": c.load_average()}


def before_after(before: str, names: list, w: int, h: int, repeats: int,
                 rounds: int) -> list[dict]:
    """The defaults' cost in two source trees (``before``, e.g. a detached
    worktree of main, and this one), each scene measured by ``rounds``
    pairs of processes in alternating order, each process importing its own
    tree's ``integrators`` (:func:`measure_time`, warm, median of ``repeats``)."""
    import json
    import os
    import subprocess
    from pathlib import Path

    here = str(Path(__file__).resolve().parents[1])
    trees = {"before": str(Path(before).resolve()), "after": here}

    def run(tree, name):
        env = {**os.environ, "PYTHONPATH": tree, "OPENBLAS_NUM_THREADS": "1"}
        out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--measure-time",
                              name, "--time-size", f"{w}x{h}", "--repeats", str(repeats)],
                             cwd=tree, env=env, capture_output=True, text=True,
                             check=True).stdout
        line = [x for x in out.splitlines() if x.startswith("RESULT ")][-1]
        return json.loads(line[len("RESULT "):])

    rows = []
    for name in names:
        for k in range(rounds):
            order = ["before", "after"] if k % 2 == 0 else ["after", "before"]
            for label in order:
                r = run(trees[label], name)
                rows.append({"tree": label, "round": k, "width": w, "height": h, **r})
                print(label, name, c.fmt(r["time_s"]), flush=True)
    return rows


def cost_table(rows: list[dict], repeats: int) -> str:
    """Median over rounds of each tree's time per scene, and after / before."""
    names = list(dict.fromkeys(r["scene"] for r in rows))
    body = []
    for n in names:
        t = {lab: float(np.median([r["time_s"] for r in rows
                                   if r["scene"] == n and r["tree"] == lab]))
             for lab in ("before", "after")}
        sc = {lab: float(np.median([r["scattering_s"] for r in rows
                                    if r["scene"] == n and r["tree"] == lab]))
              for lab in ("before", "after")}
        body.append([n, c.fmt(1000 * t["before"]), c.fmt(1000 * t["after"]),
                     c.fmt(t["after"] / t["before"]), c.fmt(1000 * sc["before"]),
                     c.fmt(1000 * sc["after"])])
    w, h = rows[0]["width"], rows[0]["height"]
    rounds = 1 + max(r["round"] for r in rows)
    return "\n\n".join([
        f"# fourier_filter defaults: cost before and after ({w}x{h}, 1 spp, warm)",
        f"Each tree in its own process, {rounds} rounds in alternating order, each the "
        f"median of {repeats} warm renders; the table takes the median over rounds.",
        c.markdown_table(["scene", "before [ms]", "after [ms]", "after / before",
                          "scattering before [ms]", "scattering after [ms]"], body)])


def random_stress(n: int, steps: int) -> list[dict]:
    """The randomised scenes of :mod:`experiments.random_scenes` (seeds
    0..n-1, their own small sizes) at the defaults against the exact
    marcher: relMSE, mean ratio, non-finite pixels; leaks against the
    unoccluded peak (the scene without its occluders)."""
    import mitsuba as mi

    from experiments.random_scenes import scene_set

    rows = []
    for spec in scene_set(n):
        row = {"seed": spec.seed, "kind": spec.kind, "light": spec.light["type"],
               "res": f"{spec.res[0]}x{spec.res[1]}", "sigma_t_B": spec.sigma_t * spec.box_half}
        try:
            scene = spec.load()
            ref = np.asarray(mi.render(scene, integrator=c.build(
                "raymarch", {"visibility": "exact", "steps": steps, "output": "scattering"})))
            img = np.asarray(mi.render(scene, integrator=c.build(
                "fourier_filter", {"output": "scattering"})))
            free = np.asarray(mi.render(spec.load(occluders=False), integrator=c.build(
                "raymarch", {"visibility": "exact", "steps": steps, "output": "scattering"})))
            peak = float(np.max(free))
            row.update(measures(img, ref) if np.max(ref) > 0 else
                       {"nonfinite": int((~np.isfinite(img)).sum())})
            row["max_over_unoccluded_peak"] = (float(np.max(np.abs(img - ref))) / peak
                                               if peak > 0 else 0.0)
            row["status"] = "ok"
        except Exception as exc:  # noqa: BLE001 -- recorded
            row["status"] = c.describe_error(exc)
        rows.append(row)
        print(spec.name, {k: c.fmt(v) for k, v in row.items()}, flush=True)
    return rows


def report(acc, thick, times, s, repeats) -> str:
    parts = [f"# fourier_filter at its defaults ({s['width']}x{s['height']}, pixel centres)",
             "Against raymarch visibility=exact "
             f"({s['reference_steps']} steps), 1 spp at pixel centres, plain scenes "
             "(scattering only). relMSE: scale-free (eps = 1e-2 · mean(ref)²). "
             f"Leak: light on reference-black pixels (ref < {BLACK:g} · peak) over the peak; "
             f"leak px: how many exceed {BLACK:g} · peak. `paper`: reference_rays=1, "
             "slice_interpolation=false, exact_fallback=false, trace_ends=false (Klehm's "
             "single reference ray on the nearest slice, the series alone: the defaults "
             "before issue 12)."]
    header = ["scene", "mode", "relMSE", "mean ratio", "max err/peak", "leak max", "leak px",
              "black px", "non-finite"]
    body = [[r["scene"], r["mode"], c.fmt(r.get("relmse")), c.fmt(r.get("mean_ratio"), 4),
             c.fmt(r.get("max_err_over_peak")), c.fmt(r.get("leak_max")), r.get("leak_pixels"),
             r.get("black_pixels"), r.get("nonfinite")] for r in acc]
    if acc:
        parts += ["## Accuracy", c.markdown_table(header, body)]
    if thick:
        taus = sorted({r["tau"] for r in thick})
        body = [[c.fmt(t)] + [c.fmt(next(r.get("mean_ratio") for r in thick
                                         if r["tau"] == t and r["mode"] == m), 4)
                              for m in MODES] for t in taus]
        parts += ["## Mean ratio against optical thickness (sun_room, σt · box diagonal)",
                  c.markdown_table(["τ"] + list(MODES), body)]
    if times:
        names = list(dict.fromkeys(r["scene"] for r in times))
        body = []
        modes = list(dict.fromkeys(r["mode"] for r in times))
        for n in names:
            by = {r["mode"]: r for r in times if r["scene"] == n}
            ms = [by[m]["time_s"] for m in modes]
            ratio = (by["default"]["time_s"] / by["before"]["time_s"]
                     if "before" in by and by["before"]["time_s"] else None)
            body.append([n, *(c.fmt(1000 * t) if t else "-" for t in ms), c.fmt(ratio),
                         str(by["default"]["load"])])
        w, h = s["time_size"]
        parts += [f"## Cost ({w}x{h}, warm end-to-end, median of {repeats}, one process)",
                  c.markdown_table(["scene", *(f"{m} [ms]" for m in modes),
                                    "default / before", "load (before, after)"], body)]
    return "\n\n".join(parts)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true")
    p.add_argument("--time", action="store_true", help="also time the suite")
    p.add_argument("--time-only", action="store_true", help="only time the suite")
    p.add_argument("--random", type=int, default=0,
                   help="only the randomised stress set: this many seeds")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--time-size", default=None, help="WxH of the timing (default 640x480)")
    p.add_argument("--scenes", nargs="+", default=None)
    p.add_argument("--out", default=None)
    p.add_argument("--before", default=None,
                   help="source tree to time the defaults against (with --time-only)")
    p.add_argument("--rounds", type=int, default=3, help="process pairs per scene (--before)")
    p.add_argument("--measure-time", default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    s = settings_for(args.quick)
    if args.scenes:
        s["scenes"] = args.scenes
    if args.time_size:
        s["time_size"] = tuple(int(v) for v in args.time_size.lower().split("x"))
    if args.measure_time:            # one tree's timing, for before_after
        import json
        w, h = s["time_size"]
        print("RESULT " + json.dumps(measure_time(args.measure_time, w, h, args.repeats)))
        return 0
    out = c.output_dir(NAME, args.out, args.quick)
    if args.before:
        w, h = s["time_size"]
        names = args.scenes or ["spot_room", "nave_onscreen"]
        rows = before_after(args.before, names, w, h, args.repeats, args.rounds)
        text = cost_table(rows, args.repeats)
        print(text)
        c.write_csv(out / "before_after.csv", rows)
        c.write_json(out / "before_after.json", {"name": NAME, "before": args.before,
                                                 "size": [w, h], "repeats": args.repeats,
                                                 "rounds": args.rounds}, rows)
        c.write_text(out / "before_after.md", text)
        return 0
    if args.random:
        rows = random_stress(args.random, s["reference_steps"])
        c.write_csv(out / "random.csv", rows)
        c.write_json(out / "random.json", {"name": NAME, "seeds": args.random,
                                           "reference_steps": s["reference_steps"]}, rows)
        return 0
    acc = [] if args.time_only else accuracy(s, out, progress=False)
    thick = [] if args.time_only else thickness(s, progress=False)
    times = timing(s, args.repeats, progress=False) if args.time or args.time_only else []
    text = report(acc, thick, times, s, args.repeats)
    print(text)
    if acc:
        c.write_csv(out / "accuracy.csv", acc)
        c.write_csv(out / "thickness.csv", thick)
    if times:
        c.write_csv(out / "timing.csv", times)
    c.write_json(out / "fourier_defaults.json", {"name": NAME, **s, "repeats": args.repeats,
                                                 "modes": MODES, "time_modes": TIME_MODES,
                                                 "black": BLACK},
                 acc, thickness=thick, timing=times)
    c.write_text(out / "table.md", text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
