"""Cost split of ``fourier_filter`` over shadow-map resolution and basis size.

Mirrors Klehm et al. 2014, **Table 2** (San Miguel, 1920x1080: "Prefix Sum +
Scattering = Sum" in ms and the memory of the filtered-basis textures for
rectified shadow maps of 512...4096 x 512...1536 texels and 16...128
coefficients) and the regions part of **Table 1** (prefilter parallelism).

Setting: ``nave_offscreen`` at 1920x1080, 1 sample per pixel at the pixel
centres, ``fourier_filter`` with ``weights=reference_ray`` (bisectrix, the
paper's default) and every other property at its default.  A rectified
shadow map of "X x Y" is ``light_rays=X`` texels per row and ``slices=Y``
epipolar slices (rows); ``slices`` is a target, the rows actually built
(slices that hold camera samples) and the rows that needed the filter are
recorded.  Per setting:

- times (median of the warm runs, see below) of the stages in
  the render's ``RenderResult.timings``: ``prefilter`` (the paper's "prefix sum": basis +
  weighted running prefix sums, Listings 1-3), ``evaluate`` (the paper's
  "scattering": per-pixel coefficients and dot products, Listing 4, plus
  the unshadowed sum U(β) and the lit-texel prefix sums), and the stages the
  paper has no counterpart for -- ``svd`` (the separated kernel giving
  U(β)), ``blockers`` (tracing the rectified shadow map; the paper excludes
  shadow-map creation), ``rectify``, ``unrectify``, ``ring``;
- memory of the filtered-basis textures, ``rows x texels x M x 4`` bytes
  (float32; the paper stores 8 bits per coefficient, i.e. 1/4 of this), both
  nominal (``slices x light_rays``) and as built (filtered rows only);
- relMSE (scale-free, eps = 1e-2·mean(ref)², DESIGN §2) and HDR-FLIP against the exact working reference
  (``raymarch visibility=exact``, 2048 steps, 1 spp at the pixel centres,
  :func:`experiments.common.exact_reference`; cached).

Table 1 part: ``regions`` = 1...4 at 1024 x 1024, M = 32 (same stage split
and error).  The paper's second knob, bases per thread, is fixed in this
implementation (16 bases per prefilter lane for every M,
:func:`integrators.fourier.prefilter._group_size`); on a CPU the rows already
give far more parallel lanes than cores, so regions can only add the
(R + 1)-lookup evaluation cost.  The kernel alone is also timed with
:func:`integrators.fourier.prefilter.bench_filter` (random rows, 1024 x 1024,
1920*1080 queries).

Timing: every setting is built once, rendered once to warm up (reported as
``first_run_s``), then rendered in ``repeats`` interleaved rounds (A, B, C,
A, B, C, ...) in one process (:func:`experiments.common.time_renders`);
medians are reported with the load average before and after.  1920x1080 is
heavy: 3 timed runs per setting (2 cores shared with other jobs).

Writes ``results/fourier_table2/``: ``table2.csv``, ``table1_regions.csv``,
``kernel_regions.csv``, ``table2.json``, ``table.md``, ``table2.png``.
``python -m experiments.fourier_table2 [--quick] [--repeats N] [--out DIR]``.

The helpers under "Shared by the fourier_* experiments" are also used by
:mod:`experiments.fourier_scene_independence`, :mod:`experiments.fourier_weights`
and :mod:`experiments.fourier_speedup`.
"""
from __future__ import annotations

import sys

import math

from . import common as c

NAME = "fourier_table2"
SCENE = "nave_offscreen"
#: the stages of fourier_filter's scattering stage, in pipeline order
STAGES = ("rectify", "blockers", "svd", "prefilter", "evaluate", "unrectify", "ring")
BYTES_PER_COEFFICIENT = 4          # float32 filtered-basis textures
#: Klehm 2014 Table 2 (GPU, NVIDIA Titan): (texels, rows, M) -> (prefix sum ms,
#: scattering ms, sum ms, MB at 8 bits per coefficient)
PAPER_TABLE2 = {
    (512, 1024, 32): (0.54, 1.47, 2.01, 16), (1024, 1024, 32): (0.94, 1.30, 2.24, 32),
    (2048, 1024, 32): (2.17, 1.31, 3.48, 64), (4096, 1024, 32): (4.32, 1.35, 5.66, 128),
    (1024, 512, 32): (0.97, 1.47, 2.44, 16), (1024, 768, 32): (1.03, 1.50, 2.53, 24),
    (1024, 1536, 32): (1.78, 1.52, 3.31, 48), (1024, 1024, 16): (0.96, 0.92, 1.88, 16),
    (1024, 1024, 64): (3.07, 2.63, 5.71, 64), (1024, 1024, 128): (4.61, 5.00, 9.61, 128),
}
#: Klehm 2014 Table 1, 4 bases per thread (the closest to one lane per
#: region here): regions -> (prefix sum ms, scattering ms, sum ms)
PAPER_TABLE1 = {1: (1.85, 0.62, 2.47), 2: (1.19, 0.96, 2.15), 3: (1.50, 1.04, 2.54),
                4: (1.28, 1.33, 2.61)}


# --------------------------------------------------------------------------
# Shared by the fourier_* experiments
# --------------------------------------------------------------------------

#: ``fourier_filter`` that records its rectified shadow maps (:func:`recording_filter`)
MAP_PROBE = "fourier_filter_map_probe"


def _register_probe():
    import mitsuba as mi

    from integrators.fourier_filter import FourierFilterIntegrator

    class MapProbe(FourierFilterIntegrator):
        """``fourier_filter`` that appends ``{"rows", "texels",
        "filtered_rows"}`` of every rectified shadow map it builds to
        ``self.map_log`` (it overrides the stage method ``rectified_map``;
        same code, same timers).  The map is already evaluated there, so
        recording costs nothing measurable."""

        def read_method_properties(self, props):
            super().read_method_properties(props)
            self.map_log = []

        def rectified_map(self, queries, rays, beta_b, **kw):
            smap = super().rectified_map(queries, rays, beta_b, **kw)
            self.map_log.append({"rows": int(smap.n), "texels": int(smap.d),
                                 "filtered_rows": int(smap.n_filtered)})
            return smap

    mi.register_integrator(MAP_PROBE, lambda props: MapProbe(props))


def recording_filter(props: dict, log: list):
    """A ``fourier_filter`` with ``props`` whose rectified shadow maps are
    appended to ``log`` as they are built (:data:`MAP_PROBE`)."""
    _register_probe()
    integ = c.build(MAP_PROBE, props)
    integ.map_log = log
    return integ


def recording_filters(runs: dict) -> tuple[dict, dict]:
    """(integrators, logs): one :func:`recording_filter` and its log per
    label of ``runs`` (label -> properties)."""
    logs = {label: [] for label in runs}
    return {label: recording_filter(props, logs[label]) for label, props in runs.items()}, logs


def paper_time(stages: dict) -> float:
    """Klehm's convention (§5: "our timings exclude rendering time for the
    creation of the shadow map"): the scattering stage minus ``blockers``
    (tracing or resampling the rectified shadow map)."""
    return stages.get("scattering", math.nan) - stages.get("blockers", 0.0)


def stage_ms(stages: dict) -> dict:
    """``<stage>_ms`` of every fourier_filter stage (0 when absent)."""
    return {f"{k}_ms": 1000.0 * stages.get(k, 0.0) for k in STAGES}


def dominant_stage(stages: dict) -> str:
    """The fourier_filter stage with the largest median time."""
    return max(STAGES, key=lambda k: stages.get(k, 0.0))


def timing_columns(t: dict) -> dict:
    """The flat timing columns of one :func:`experiments.common.time_renders`
    result: end-to-end, scattering, paper convention, first run, stages."""
    return {"time_s": t["time_s"], "time_min_s": t["time_min_s"], "time_max_s": t["time_max_s"],
            "first_run_s": t["first_run_s"], "scattering_s": t["scattering_s"],
            "paper_s": paper_time(t["stages"]), **stage_ms(t["stages"]),
            "dominant_stage": dominant_stage(t["stages"]), "stages": t["stages"]}


def load_text(loads: list) -> str:
    """'1/5/15-min load averages: first [..], max 1-min x' for a report."""
    return (f"load average (1/5/15 min, as `uptime`) over the runs: first {loads[0]}, "
            f"last {loads[-1]}, max 1-min {max(l[0] for l in loads)}")


# --------------------------------------------------------------------------
# Settings
# --------------------------------------------------------------------------

def settings_for(quick: bool) -> dict:
    """Resolution, the (texels, rows, M) grid, regions, reference steps."""
    if quick:
        return {"width": 96, "height": 54, "reference_steps": 128,
                "grid": [(64, 64, 32), (128, 64, 32), (64, 64, 16)], "base": (64, 64, 32),
                "regions": [1, 2], "kernel": {"n_rows": 64, "n": 64, "pixels": 96 * 54}}
    return {"width": 1920, "height": 1080, "reference_steps": c.REFERENCE_STEPS,
            "grid": list(PAPER_TABLE2), "base": (1024, 1024, 32), "regions": [1, 2, 3, 4],
            "kernel": {"n_rows": 1024, "n": 1024, "pixels": 1920 * 1080}}


def runs_of(s: dict) -> dict:
    """label -> fourier_filter properties of every measured setting (the
    Table 2 grid, then the extra regions of Table 1 at the base setting)."""
    out = {}
    for texels, rows, M in s["grid"]:
        out[f"{texels}x{rows} M{M}"] = {"light_rays": texels, "slices": rows, "coefficients": M}
    texels, rows, M = s["base"]
    for r in s["regions"]:
        if r > 1:
            out[f"{texels}x{rows} M{M} R{r}"] = {"light_rays": texels, "slices": rows,
                                                 "coefficients": M, "regions": r}
    return out


# --------------------------------------------------------------------------
# Measuring
# --------------------------------------------------------------------------

def memory_mb(rows: int, texels: int, M: int) -> float:
    """Filtered-basis textures in MiB: rows x texels x M float32 values."""
    return rows * texels * M * BYTES_PER_COEFFICIENT / 2.0**20


def measure(scene_name: str, s: dict, repeats: int, progress: bool) -> list[dict]:
    """Every setting of :func:`runs_of` on one scene: times, memory, errors."""
    scene, ref, info = c.scene_with_reference(scene_name, s, progress)
    runs = runs_of(s)
    integs, logs = recording_filters(runs)
    load_before = c.load_average()
    timed = c.time_renders(scene, integs, repeats=repeats, progress=progress)
    load_after = c.load_average()
    return [{"scene": scene_name, **row_of(label, props, timed[label], logs[label], ref, info,
                                           s, load_before, load_after)}
            for label, props in runs.items()]


def row_of(label, props, t, log, ref, info, s, load_before, load_after) -> dict:
    """One table row: the setting, its shadow map as built, times, memory,
    errors and the paper's numbers for the same setting."""
    texels, slices, M = props["light_rays"], props["slices"], props["coefficients"]
    row = {"setting": label, "width": s["width"], "height": s["height"],
           "texels": texels, "slices": slices, "M": M, "regions": props.get("regions", 1),
           "status": t.get("error", "ok"), "load_before": load_before, "load_after": load_after,
           "reference": info["path"]}
    if "error" in t:
        return row
    built = log[-1] if log else {}
    row.update(rows_built=built.get("rows"), filtered_rows=built.get("filtered_rows"),
               texels_built=built.get("texels"),
               memory_mb_nominal=memory_mb(slices, texels, M),
               memory_mb_built=memory_mb(built.get("filtered_rows", 0), texels, M))
    row.update(timing_columns(t))
    row["prefilter_plus_evaluate_ms"] = row["prefilter_ms"] + row["evaluate_ms"]
    row.update(c.errors(t["image"], ref))
    paper = PAPER_TABLE2.get((texels, slices, M)) if row["regions"] == 1 else None
    if paper:
        row.update(paper_prefix_ms=paper[0], paper_scattering_ms=paper[1],
                   paper_sum_ms=paper[2], paper_mb_8bit=paper[3])
    return row


def kernel_regions(s: dict, repeats: int) -> list[dict]:
    """:func:`integrators.fourier.prefilter.bench_filter` (the prefilter and
    evaluation kernels alone, random rows) for each number of regions."""
    from integrators.fourier.prefilter import bench_filter

    k = s["kernel"]
    out = []
    for r in s["regions"]:
        res = bench_filter(n_rows=k["n_rows"], n=k["n"], M=s["base"][2], pixels=k["pixels"],
                           regions=r, reps=max(repeats, 1))
        out.append({**res, "load": c.load_average()})
    return out


# --------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------

def _ms(v) -> str:
    return c.fmt(v, 3) if isinstance(v, (int, float)) else "-"


def table2_text(rows: list[dict]) -> str:
    """Table 2 layout plus the stages the paper does not have."""
    header = ["shadow map (texels x slices)", "rows built / filtered", "M",
              "prefilter [ms]", "evaluate [ms]", "= sum [ms]", "svd [ms]", "blockers [ms]",
              "scattering [ms]", "total [ms]", "memory MiB (nominal / built, fp32)",
              "relMSE", "FLIP", "paper: prefix + scattering = sum [ms], MB (8 bit)"]
    body = []
    for r in rows:
        if r["regions"] != 1:
            continue
        if r["status"] != "ok":
            body.append([f"{r['texels']}x{r['slices']}", "-", r["M"], *["-"] * 10, r["status"]])
            continue
        paper = (f"{r['paper_prefix_ms']} + {r['paper_scattering_ms']} = {r['paper_sum_ms']}, "
                 f"{r['paper_mb_8bit']}") if "paper_sum_ms" in r else "-"
        body.append([f"{r['texels']}x{r['slices']}", f"{r['rows_built']} / {r['filtered_rows']}",
                     r["M"], _ms(r["prefilter_ms"]), _ms(r["evaluate_ms"]),
                     _ms(r["prefilter_plus_evaluate_ms"]), _ms(r["svd_ms"]),
                     _ms(r["blockers_ms"]), _ms(1000 * r["scattering_s"]),
                     _ms(1000 * r["time_s"]),
                     f"{c.fmt(r['memory_mb_nominal'])} / {c.fmt(r['memory_mb_built'])}",
                     c.fmt(r["relmse_b1"]), c.fmt(r["flip_b1"]), paper])
    return c.markdown_table(header, body)


def table1_text(rows: list[dict], kernel: list[dict], base: tuple) -> str:
    """Regions: integrator stages and kernel-only times, +% vs 1 region."""
    texels, slices, M = base
    mine = [r for r in rows if r["status"] == "ok" and (r["texels"], r["slices"], r["M"]) == base]
    mine.sort(key=lambda r: r["regions"])
    k_by = {k["regions"]: k for k in kernel}
    header = ["regions", "prefilter [ms]", "evaluate [ms]", "= sum [ms]", "+% vs 1 region",
              "relMSE", "kernel only: prefilter + evaluate [ms]",
              "paper (4 bases/thread): prefix + scattering = sum [ms]"]
    body = []
    one = mine[0]["prefilter_plus_evaluate_ms"] if mine else math.nan
    for r in mine:
        k = k_by.get(r["regions"])
        kern = (f"{1000 * k['prefilter_s']:.1f} + {1000 * k['evaluate_s']:.1f}" if k else "-")
        p = PAPER_TABLE1.get(r["regions"])
        body.append([r["regions"], _ms(r["prefilter_ms"]), _ms(r["evaluate_ms"]),
                     _ms(r["prefilter_plus_evaluate_ms"]),
                     f"{100 * (one / r['prefilter_plus_evaluate_ms'] - 1):+.0f}%",
                     c.fmt(r["relmse_b1"]), kern,
                     f"{p[0]} + {p[1]} = {p[2]}" if p else "-"])
    return (f"{texels} x {slices}, M = {M}; bases per prefilter lane fixed at 16 "
            "(not a parameter here).  '+%' as in the paper: speed gain of (prefilter + "
            "evaluate) over 1 region.\n\n" + c.markdown_table(header, body))


def report(rows, kernel, s, repeats, scene_name) -> str:
    loads = [r["load_before"] for r in rows] + [r["load_after"] for r in rows]
    loads += [k["load"] for k in kernel]
    ok = [r for r in rows if r["status"] == "ok"]
    dom = sorted({r["dominant_stage"] for r in ok})
    return "\n\n".join([
        f"# fourier_table2: Klehm 2014 Table 2 (and Table 1 regions) on {scene_name}, "
        f"{s['width']}x{s['height']}",
        f"CPU (Dr.Jit LLVM, {c.environment()['drjit_threads']} threads), median of {repeats} "
        f"warm runs after a warm-up, interleaved rounds in one process; "
        f"{load_text(loads)}.  Errors: {c.reference_note(s['reference_steps'])} "
        "(block 1 = per pixel).  'prefilter' = the paper's prefix sum, 'evaluate' = its "
        "per-pixel scattering; 'svd' and 'blockers' have no column in the paper "
        f"(largest stage per setting: {', '.join(dom)}).",
        "## Table 2", table2_text(rows),
        "## Table 1 (regions)", table1_text(rows, kernel, s["base"])])


def plot(path, rows: list[dict]) -> None:
    """Stacked stage times per setting (left) and relMSE (right)."""
    plt = c.pyplot()
    ok = [r for r in rows if r["status"] == "ok"]
    labels = [r["setting"] for r in ok]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10, 3.8), gridspec_kw={"width_ratios": [3, 1.4]})
    bottom = [0.0] * len(ok)
    for stage in ("prefilter", "evaluate", "svd", "blockers", "rectify", "unrectify", "ring"):
        vals = [r[f"{stage}_ms"] for r in ok]
        ax.bar(range(len(ok)), vals, bottom=bottom, label=stage)
        bottom = [b + v for b, v in zip(bottom, vals)]
    ax.set_xticks(range(len(ok)), labels, rotation=60, ha="right", fontsize=7)
    ax.set_ylabel("median stage time [ms]")
    ax.set_title("fourier_filter scattering stages (texels x slices, M, regions)", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    ax2.plot(range(len(ok)), [r["relmse_b1"] for r in ok], "o")
    ax2.set_yscale("log")
    ax2.set_xticks(range(len(ok)), labels, rotation=60, ha="right", fontsize=7)
    ax2.set_ylabel("relMSE vs exact")
    ax2.grid(True, which="both", alpha=0.3)
    c.savefig(fig, path)


def main(argv=None):
    run = c.start_run(sys.modules[__name__], argv, [SCENE], [SCENE])
    args, s, repeats, out = run.args, run.settings, run.repeats, run.out
    scene_name = run.scenes[0]
    rows = measure(scene_name, s, repeats, progress=not args.quick)
    kernel = kernel_regions(s, repeats)
    text = report(rows, kernel, s, repeats, scene_name)
    print(text)
    settings = {"name": NAME, "scene": scene_name, **s, "repeats": repeats, "runs": runs_of(s),
                "reference": c.reference_note(s["reference_steps"]),
                "memory": "rows x texels x M x 4 bytes (float32), MiB",
                "quick": args.quick}
    c.write_csv(out / "table2.csv", [r for r in rows if r["regions"] == 1])
    c.write_csv(out / "table1_regions.csv",
                [r for r in rows if (r["texels"], r["slices"], r["M"]) == tuple(s["base"])])
    c.write_csv(out / "kernel_regions.csv", kernel)
    c.write_json(out / "table2.json", settings, rows, kernel_regions=kernel)
    c.write_text(out / "table.md", text)
    plot(out / "table2.png", rows)
    return rows, kernel


if __name__ == "__main__":
    main()
