"""``epipolar_tree`` (or ``--method``) at its defaults on the suite, before and
after a change (issue 13, "the suite's accuracy and speed at defaults
unchanged or better").

Each scene is measured by two processes in turn, one per source tree
(``--before TREE``: e.g. a detached worktree of main; the other: this
tree), each importing its own ``integrators``: a warm-up render, then
``--repeats`` timed renders (median), 1 spp at the **pixel centres**, against
the cached exact working reference (raymarch visibility=exact, 2048 steps,
12 boundary bisections, :func:`experiments.common.scene_with_reference`)
of *this* tree: each process saves its image and the parent judges both,
so an old tree's reference code does not enter.  Errors: scale-free
relMSE (eps 1e-2·mean(ref)²), mean ratio, max |error| / reference peak,
HDR-FLIP, of the full image.  The order of the two processes alternates
from scene to scene.

``python -m experiments.suite_before_after --before /work/wt/h13-main
[--scenes ...] [--method fourier_filter] [--size 320x240] [--after-props JSON]
[--out results/stability]``
writes ``suite_before_after.json`` and ``.md``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

SUITE = ["nave_offscreen", "nave_onscreen", "grove", "terrain", "spot_room", "point_fog", "beam"]
WIDTH, HEIGHT = 640, 480


def measure(scene_name: str, repeats: int, method: str = "epipolar_tree",
            width: int = WIDTH, height: int = HEIGHT, image_out: str | None = None,
            props: dict | None = None) -> dict:
    """This process's tree: median times of ``method`` at its defaults (or
    with ``props``) on one suite scene, 1 spp; the image is saved to
    ``image_out`` (``.npy``) so that the parent judges both trees against
    one reference."""
    import numpy as np
    from experiments import common as c

    scene = c.load(c.scene_file(scene_name), c.resolution(width, height))
    t = c.time_renders(scene, {"m": c.build(method, props or {})}, repeats=repeats, spp=1)["m"]
    if image_out:
        np.save(image_out, np.asarray(t["image"], dtype=np.float32))
    return {"scene": scene_name, "time_s": t["time_s"], "time_min_s": min(t["times_s"]),
            "times_s": t["times_s"], "scattering_s": t["scattering_s"],
            "load": c.load_average()}


def reference_of(scene_name: str, width: int, height: int):
    """This tree's cached exact working reference of a suite scene
    (:func:`experiments.common.scene_with_reference`)."""
    from experiments import common as c

    s = {"width": width, "height": height, "reference_steps": c.REFERENCE_STEPS}
    return c.scene_with_reference(scene_name, s, False)[1]


def judged(image, ref) -> dict:
    """Errors of ``image`` against the reference ``ref``."""
    from experiments import common as c

    e = c.errors(image, ref, blocks=(1,))
    return {"relmse": e["relmse_b1"], "mean_ratio": e["mean_ratio_b1"],
            "max_err_over_peak": e["max_error_over_peak_b1"], "flip": e["flip_b1"]}


def run_tree(tree: str, scene: str, repeats: int, method: str = "epipolar_tree",
             size: str = f"{WIDTH}x{HEIGHT}", props: dict | None = None):
    """(row, image): :func:`measure` in a subprocess importing ``tree``'s
    packages (this file run with ``--measure`` from ``tree``; ``props``: the
    method's properties, default none), and the image it rendered, for the
    caller to judge against one reference."""
    import tempfile

    import numpy as np

    with tempfile.TemporaryDirectory() as tmp:
        image_out = str(Path(tmp) / "image.npy")
        env = {**os.environ, "PYTHONPATH": tree, "OPENBLAS_NUM_THREADS": "1"}
        out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--measure", scene,
                              "--repeats", str(repeats), "--method", method, "--size", size,
                              "--image-out", image_out] + (
                                 ["--props", json.dumps(props)] if props else []),
                             cwd=tree, env=env, capture_output=True, text=True, check=True).stdout
        image = np.load(image_out)
    line = [x for x in out.splitlines() if x.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT "):]), image


def table(rows: list[dict]) -> str:
    nan = float("nan")
    def f(x, d=3):
        return f"{x:.{d}g}"
    out = ["| scene | relMSE before -> after | mean ratio before -> after | max err/peak "
           "before -> after | FLIP before -> after | time before / after [s] | ratio | "
           "fastest-run ratio | scattering ratio | after image = before |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    by = {}
    for r in rows:
        by.setdefault(r["scene"], {})[r["version"]] = r
    for scene, v in by.items():
        b, a = v["before"], v["after"]
        out.append(f"| {scene} | {f(b['relmse'])} -> {f(a['relmse'])} | {b['mean_ratio']:.4f} -> "
                   f"{a['mean_ratio']:.4f} | {f(b['max_err_over_peak'])} -> "
                   f"{f(a['max_err_over_peak'])} | {b['flip']:.4f} -> {a['flip']:.4f} | "
                   f"{b['time_s']:.2f} / {a['time_s']:.2f} | {a['time_s'] / b['time_s']:.2f} | "
                   f"{a.get('time_min_s', nan) / b.get('time_min_s', nan):.2f} | "
                   f"{a['scattering_s'] / b['scattering_s']:.2f} | "
                   f"{'yes' if a.get('identical') else 'no'} |")
    return "\n".join(out)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--before", help="source tree of the 'before' version")
    p.add_argument("--measure", metavar="SCENE", help=argparse.SUPPRESS)
    p.add_argument("--image-out", help=argparse.SUPPRESS)
    p.add_argument("--after", default=str(Path(__file__).resolve().parents[1]),
                   help="source tree of the 'after' version (default: this one)")
    p.add_argument("--scenes", nargs="+", default=SUITE)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--method", default="epipolar_tree", help="integrator (default epipolar_tree)")
    p.add_argument("--size", default=f"{WIDTH}x{HEIGHT}", help="WxH (default 640x480)")
    p.add_argument("--after-props", default="{}", metavar="JSON",
                   help="properties of the after version's renders, e.g. "
                        "'{\"remarch_disagreement\": 1.0}' (default: its defaults)")
    p.add_argument("--props", default="{}", help=argparse.SUPPRESS)
    p.add_argument("--against-before", action="store_true",
                   help="judge the after image against the before image (no reference: "
                        "is the image unchanged?) instead of the exact reference")
    p.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "results/stability"))
    args = p.parse_args(argv)
    width, height = (int(x) for x in args.size.lower().split("x"))
    if args.measure:
        print("RESULT " + json.dumps(measure(args.measure, args.repeats, args.method, width,
                                             height, args.image_out, json.loads(args.props))),
              flush=True)
        return
    if not args.before:
        p.error("--before TREE is required")
    import numpy as np

    rows = []
    for i, scene in enumerate(args.scenes):
        ref = None if args.against_before else reference_of(scene, width, height)
        order = [("before", args.before), ("after", args.after)]
        done = {}
        for version, tree in (order if i % 2 == 0 else order[::-1]):
            props = json.loads(args.after_props) if version == "after" else None
            done[version] = run_tree(tree, scene, args.repeats, args.method, args.size, props)
        for version, tree in order:
            r, image = done[version]
            r = {**r, **judged(image, done["before"][1] if ref is None else ref),
                 "identical": bool(np.array_equal(image, done["before"][1])),
                 "version": version, "tree": tree}
            print(json.dumps(r), flush=True)
            rows.append(r)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "suite_before_after.json").write_text(json.dumps(rows, indent=1))
    text = "\n\n".join([
        f"# {args.method} at its defaults on the suite, before and after",
        f"{width}x{height}, 1 spp at **pixel centres**, "
        + ("the after image against the before image (errors 0 and 'identical': unchanged). "
           if args.against_before else
           "both versions against the exact working reference of the tree running the script "
           "(by default the after tree) (raymarch visibility=exact, 2048 steps, 12 boundary "
           "bisections, crack confirmation; cached). ")
        + "Scale-free relMSE (eps 1e-2 x "
        "mean(ref)^2), mean ratio, max |error| / reference peak, HDR-FLIP; end-to-end and "
        f"scattering time: median of {args.repeats} warm runs (and the ratio of the fastest runs), OPENBLAS_NUM_THREADS=1, the two "
        "versions in alternating processes per scene (experiments.suite_before_after). "
        f"Before: {args.before}; after: {args.after}"
        + (f" with {args.after_props}" if json.loads(args.after_props) else "")
        + ". Load averages in the JSON.",
        table(rows)])
    (out / "suite_before_after.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
