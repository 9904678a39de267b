"""Frame to frame: what an animation pays per frame with each integrator
(kernel recompiles when the camera, the light or the medium change).

``python -m experiments.frame_to_frame [--scenes ...] [--methods ...]
[--size 640x480] [--frames 6] [--warm-repeats 3] [--empty-cache] [--out DIR]``

Each (scene, method) pair renders a fly-through
(:func:`episcatter.flythrough.fly_through`) in a fresh Python process of its
own, so that frame 0 is the first render in the process (Dr.Jit's disk
cache as this machine has it; ``--prime`` fills it first with one throwaway
run of frame 0, so that frame 0 is "a second launch of the program": its
kernels on disk).  Frames 1, 2 move the camera a few cm along its x axis,
frame 3 moves the light (a point light 5 cm, a directional / spot light
1.5°), frame 4 scales σt by 3 %, frame 5 changes all three (then the cycle
repeats).  Per frame: the first render's wall time, the JIT kernels it
launched / compiled / took from the disk cache and their compile time
(:mod:`episcatter.kernels`), and the median of ``--warm-repeats`` more
renders of the same frame (warm).  ``compile share = compile_s / wall``,
``ratio = wall / warm``.

``--empty-cache`` also runs frame 0 of each pair in a fresh process whose
Dr.Jit kernel cache (``DRJIT_CACHE_DIR``) is a new empty folder: the first
render of a fresh install.

Scenes (suite stems, or an XML path): ``nave_offscreen`` (directional),
``point_fog`` (point), ``spot_room_plain`` (``spot_room`` with its
``<texture>`` removed: a plain spot) and ``spot_room`` (textured spot).
Methods: ``raymarch``, ``epipolar_tree``, ``fourier_filter``,
``minmax_epipolar``, and ``quality_auto`` (``epipolar_tree quality=auto
error_budget=--error-budget``).

Writes ``frames.csv`` (one row per scene, method, frame), ``pairs.csv``
(one row per pair: the summary), ``table.md``, ``frames.json`` and
``environment.json`` into ``results/frame_to_frame/<tag>`` (``--out``).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time

from experiments import common

NAME = "frame_to_frame"
SCENES = ["nave_offscreen", "point_fog", "spot_room_plain", "spot_room"]
METHODS = ["raymarch", "epipolar_tree", "fourier_filter", "minmax_epipolar"]
#: pseudo-methods: name -> (integrator type, properties)
PSEUDO = {"quality_auto": ("epipolar_tree", {"quality": "auto"})}
#: scene stems that are a suite scene with a change (name -> (stem, change))
PLAIN_SPOT = "spot_room_plain"
EMITTER = {"nave_offscreen": "directional", "point_fog": "point", PLAIN_SPOT: "spot",
           "spot_room": "spot (textured)"}
DEFAULT_ERROR_BUDGET = 1e-4
FRAME_CSV_COLUMNS = ("scene", "method", "width", "height")


# --------------------------------------------------------------------------
# Scenes and methods
# --------------------------------------------------------------------------

def load_scene(name: str, width: int, height: int):
    """Scene ``name`` at width×height: a suite stem, ``spot_room_plain``
    (``spot_room`` without its projected texture) or an XML path."""
    import mitsuba as mi

    defines = common.resolution(width, height)
    if name != PLAIN_SPOT:
        return common.load(common.scene_file(name), defines)
    from experiments.spot_texture_cost import TEXTURE

    path = common.scene_file("spot_room")
    xml, n = TEXTURE.subn("", open(path).read())
    if n != 1:
        raise ValueError("spot_room.xml no longer has exactly one bitmap <texture>.")
    cwd = os.getcwd()
    os.chdir(os.path.dirname(path))          # relative asset paths
    try:
        return mi.load_string(xml, **{k: str(v) for k, v in defines.items()})
    finally:
        os.chdir(cwd)


def method_spec(method: str, error_budget: float = DEFAULT_ERROR_BUDGET) -> tuple[str, dict]:
    """(integrator type, properties) of a method name (:data:`PSEUDO`)."""
    if method in PSEUDO:
        kind, props = PSEUDO[method]
        return kind, {**props, "error_budget": float(error_budget)}
    return method, {}


def build_method(method: str, error_budget: float = DEFAULT_ERROR_BUDGET):
    kind, props = method_spec(method, error_budget)
    return common.build(kind, props)


# --------------------------------------------------------------------------
# One pair (run in its own process unless --in-process)
# --------------------------------------------------------------------------

def measure_pair(scene: str, method: str, width: int, height: int, frames: int,
                 warm_repeats: int, seed: int | None, error_budget: float) -> dict:
    """The fly-through of one (scene, method) pair in this process:
    ``{"rows": [...], "seed": ..., "integrators_file": ...}``."""
    import integrators
    from episcatter.blas import limit_blas_threads
    from episcatter.flythrough import Motion, fly_through

    sc = load_scene(scene, width, height)
    integ = build_method(method, error_budget)
    motion = Motion(seed=seed).fresh()
    with limit_blas_threads(1):
        rows = fly_through(sc, integ, frames=frames, warm_repeats=warm_repeats, motion=motion)
    return {"rows": rows, "seed": motion.seed, "integrators_file": integrators.__file__}


def run_worker(args) -> int:
    """``--worker``: one pair, its result as JSON into ``--result``."""
    w, h = _size(args.size)
    try:
        out = measure_pair(args.scenes[0], args.methods[0], w, h, args.frames,
                           args.warm_repeats, args.seed, args.error_budget)
    except Exception as exc:  # noqa: BLE001 -- reported by the parent
        out = {"error": common.describe_error(exc)}
    with open(args.result, "w") as f:
        json.dump(out, f)
    return 0


def run_subprocess(scene: str, method: str, args, frames: int, warm_repeats: int,
                   cache_dir: str | None = None) -> dict:
    """:func:`measure_pair` in a fresh Python process (same interpreter,
    environment and working directory; ``cache_dir``: its
    ``DRJIT_CACHE_DIR``)."""
    env = dict(os.environ)
    if cache_dir is not None:
        env["DRJIT_CACHE_DIR"] = cache_dir
    with tempfile.TemporaryDirectory(prefix="f2f_") as tmp:
        result = os.path.join(tmp, "result.json")
        cmd = [sys.executable, "-m", "experiments.frame_to_frame", "--worker",
               "--scenes", scene, "--methods", method, "--size", args.size,
               "--frames", str(frames), "--warm-repeats", str(warm_repeats),
               "--error-budget", repr(args.error_budget), "--result", result]
        if args.seed is not None:
            cmd += ["--seed", str(args.seed)]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
        seconds = time.perf_counter() - t0
        if proc.returncode != 0 or not os.path.exists(result):
            tail = (proc.stderr or proc.stdout or "").strip().splitlines()[-5:]
            return {"error": f"failed: worker exit {proc.returncode}: " + " / ".join(tail),
                    "process_s": seconds}
        with open(result) as f:
            out = json.load(f)
    out["process_s"] = seconds
    return out


def _size(text: str) -> tuple[int, int]:
    s = common.sized({"width": 0, "height": 0}, text)
    return s["width"], s["height"]


# --------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------

def pair_summary(scene: str, method: str, out: dict) -> dict:
    from episcatter.flythrough import summarize_frames

    row = {"scene": scene, "light": EMITTER.get(scene, ""), "method": method}
    if out.get("error"):
        return {**row, "error": out["error"]}
    row.update(summarize_frames(out["rows"]))
    cold = out.get("empty_cache")
    if cold is not None:
        if cold.get("error"):
            row["cold_error"] = cold["error"]
        else:
            c = cold["rows"][0]
            row.update(cold_first_s=c["wall_s"], cold_compile_s=c["compile_s"],
                       cold_compiled=c["compiled"], cold_launched=c["launched"])
    row["seed"] = out.get("seed")
    return row


def _share(x) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{100 * x:.0f} %"


def report(pairs: list[dict], settings: dict) -> str:
    f = common.fmt
    cold = any("cold_first_s" in p or "cold_error" in p for p in pairs)
    header = ["scene", "method", "first render s"]
    header += ["first, empty cache s (compile s)"] if cold else []
    header += ["new frame mean s", "new frame max s", "warm s", "max ratio",
               "max compile share", "launched / frame", "compiled / new frame (max)"]
    rows = []
    for p in pairs:
        if p.get("error"):
            rows.append([p["scene"], p["method"], p["error"]] + [""] * (len(header) - 3))
            continue
        r = [p["scene"], p["method"],
             f"{f(p['first_s'])} ({p['first_compiled']} compiled, "
             f"{p['first_from_disk']} from disk)"]
        if cold:
            r.append(p.get("cold_error") or
                     (f"{f(p['cold_first_s'])} ({f(p['cold_compile_s'])})"
                      if "cold_first_s" in p else "-"))
        launched = (f"{p['launched_min']}" if p["launched_min"] == p["launched_max"]
                    else f"{p['launched_min']}-{p['launched_max']}")
        r += [f(p["new_mean_s"]), f(p["new_max_s"]), f(p["warm_s"]), f(p["max_ratio"]),
              _share(p["max_compile_share"]), launched,
              f"{f(p['compiled_mean'], 2)} ({f(p['compiled_max'])})"]
        rows.append(r)
    s = settings
    text = [f"# Frame to frame: {s['width']}x{s['height']}, {s['frames']} frames, "
            f"{s['warm_repeats']} warm renders per frame", "",
            common.markdown_table(header, rows), "",
            "first render: frame 0, the first render in its process (kernels compiled / "
            "loaded from Dr.Jit's disk cache"
            + ("; primed with one throwaway run" if s.get("prime") else "") + "). "
            "New frames 1.. change the scene in place (mi.traverse + params.update): "
            + s["schedule"] + ". wall = first render of a frame (mi.render spp=1, dr.eval + "
            "sync); warm = median of the warm renders of the same frame; ratio = wall / warm "
            "(max over the new frames); compile share = compile time / wall (max over the new "
            "frames); compiled = kernels not found in memory or on disk."]
    if cold:
        text.append("")
        text.append("first, empty cache: frame 0 in a fresh process with an empty "
                    "DRJIT_CACHE_DIR (wall s, compile s).")
    if s.get("integrators_file"):
        text += ["", f"integrators: `{s['integrators_file']}`"]
    return "\n".join(text)


# --------------------------------------------------------------------------
# Main
# --------------------------------------------------------------------------

def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenes", nargs="+", default=SCENES,
                   help=f"suite stems, {PLAIN_SPOT} or XML paths (default {' '.join(SCENES)})")
    p.add_argument("--methods", nargs="+", default=METHODS,
                   help=f"integrators (default {' '.join(METHODS)}; also "
                        f"{', '.join(PSEUDO)})")
    p.add_argument("--size", default="640x480", metavar="WxH", help="image size (640x480)")
    p.add_argument("--frames", type=int, default=6, help="frames per fly-through (6)")
    p.add_argument("--warm-repeats", type=int, default=3,
                   help="warm renders of each frame (median; 3)")
    p.add_argument("--error-budget", type=float, default=DEFAULT_ERROR_BUDGET,
                   help=f"relMSE budget of quality_auto (default {DEFAULT_ERROR_BUDGET:g})")
    p.add_argument("--seed", type=int, default=None,
                   help="seed of the motions' random extras (default: a new one per pair, so "
                        "that new frames never come from a previous run's disk cache)")
    p.add_argument("--empty-cache", action="store_true",
                   help="also render frame 0 of each pair in a fresh process with an empty "
                        "Dr.Jit kernel cache (DRJIT_CACHE_DIR)")
    p.add_argument("--prime", action="store_true",
                   help="run frame 0 of each pair once in a throwaway process first, so that "
                        "frame 0 finds its kernels in the disk cache")
    p.add_argument("--in-process", action="store_true",
                   help="run every pair in this process (frame 0 of later pairs then shares "
                        "kernels with earlier ones; for tests)")
    p.add_argument("--tag", default=None, help="output subfolder (default WxH)")
    p.add_argument("--out", default=None,
                   help="output folder (default results/frame_to_frame/<tag>)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--result", default=None, help=argparse.SUPPRESS)
    return p


def main(argv=None) -> list[dict]:
    args = parser().parse_args(argv)
    if args.worker:
        return run_worker(args)
    from tqdm.auto import tqdm

    from episcatter.flythrough import CHANGES

    w, h = _size(args.size)
    if args.frames < 1 or args.warm_repeats < 1:
        raise SystemExit("--frames and --warm-repeats must be >= 1")
    for m in args.methods:
        if m not in PSEUDO and m not in METHODS:
            print(f"note: {m} is not one of {METHODS + list(PSEUDO)}; building it as given",
                  flush=True)
    out = common.output_dir(NAME, args.out or str(common.RESULTS / NAME / (args.tag or f"{w}x{h}")))
    pairs = [(s, m) for s in args.scenes for m in args.methods]
    frame_rows, summaries, files = [], [], set()
    bar = tqdm(pairs, desc="scene x method", disable=args.no_progress)
    for scene, method in bar:
        bar.set_postfix_str(f"{scene} {method}")
        if args.in_process:
            try:
                res = measure_pair(scene, method, w, h, args.frames, args.warm_repeats,
                                   args.seed, args.error_budget)
            except Exception as exc:  # noqa: BLE001 -- recorded, the others go on
                res = {"error": common.describe_error(exc)}
        else:
            if args.prime:
                run_subprocess(scene, method, args, 1, 0)
            res = run_subprocess(scene, method, args, args.frames, args.warm_repeats)
        if args.empty_cache:
            with tempfile.TemporaryDirectory(prefix="drjit_cache_") as cache:
                res["empty_cache"] = run_subprocess(scene, method, args, 1, 1, cache_dir=cache)
        if res.get("integrators_file"):
            files.add(res["integrators_file"])
        for r in res.get("rows", []):
            frame_rows.append({"scene": scene, "method": method, "width": w, "height": h, **r,
                               "seed": res.get("seed")})
        for r in (res.get("empty_cache") or {}).get("rows", []):
            frame_rows.append({"scene": scene, "method": method, "width": w, "height": h, **r,
                               "frame": 0, "change": "first_empty_cache",
                               "seed": res["empty_cache"].get("seed")})
        summaries.append({**pair_summary(scene, method, res),
                          "load_1min": common.load_average()[0]})
        line = summaries[-1]
        tqdm.write(f"{scene} {method}: " + (line.get("error") or
                   f"first {line['first_s']:.3g} s, new frames {line['new_mean_s']:.3g} s mean, "
                   f"warm {line['warm_s']:.3g} s, {line['compiled_mean']:.3g} compiled / new "
                   f"frame"), file=sys.stderr)
        # checkpoint what we have so far
        common.write_csv(out / "frames.csv", frame_rows)
    bar.close()
    schedule = ("frames " + ", ".join(f"{k + 1}: {c}" for k, c in enumerate(CHANGES))
                + " (cycled); camera +5 cm along its x axis, light: point +5 cm along x, "
                  "directional / spot 1.5 deg about its x axis, medium: sigma_t x 1.03 "
                  "(each +- a 2 % random extra)")
    settings = {"name": NAME, "width": w, "height": h, "frames": args.frames,
                "warm_repeats": args.warm_repeats, "scenes": args.scenes,
                "methods": args.methods, "error_budget": args.error_budget,
                "empty_cache": args.empty_cache, "prime": args.prime,
                "in_process": args.in_process, "schedule": schedule, "spp": 1,
                "integrators_file": ", ".join(sorted(files)),
                "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
                "argv": sys.argv[1:] if argv is None else list(argv)}
    text = report(summaries, settings)
    common.write_csv(out / "frames.csv", frame_rows)
    common.write_csv(out / "pairs.csv", summaries)
    common.write_json(out / "frames.json", settings, frame_rows, pairs=summaries)
    with open(out / "environment.json", "w") as f:
        json.dump({"settings": settings, "environment": common.environment()}, f, indent=2)
        f.write("\n")
    common.write_text(out / "table.md", text)
    print(text)
    print(f"wrote {out}/frames.csv, pairs.csv, table.md, frames.json, environment.json")
    return summaries


if __name__ == "__main__":
    result = main()
    sys.exit(result if isinstance(result, int) else 0)
