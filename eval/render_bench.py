"""``python -m eval render-bench``: how fast the renderer is, and what its samples buy.

Two measurements on one scene (default ``scenes/paper_plane.xml`` at full size), wall clock,
reading the image back (Dr.Jit is lazy: the work happens when the result is read):

1. **Throughput against the wavefront size**: the left view rendered with ``--per-call`` spp in
   each ``mi.render`` call, as many calls as reach ``--throughput-spp`` samples per pixel;
   samples per second for each.
2. **Side by side**: both views at the scene's spp, one ``mi.render`` call per view against
   the pass plan, timed one after the other in the same process.
3. **Accuracy against time**: both views rendered with the project's pass plan
   (:func:`synth.render.pass_plan`) at each total spp of ``--spp``, the targets detected and
   compared with the Fermat simulator (against each centre's pixel and against the outline
   centroid); cross-check RMS (px) against render seconds.

Writes ``DIR/render_bench.json`` and ``DIR/render_curve.png`` (``--out``, the project's output
rule). Speeds are measured here, never in tests.
"""

from __future__ import annotations

import os
import sys
import time

from eval.cli import CLIError, positive_int
from synth.cli import add_define_option, add_out_option, add_progress_option, add_scene_argument

COMMAND = "eval render-bench"


def add_parser(subparsers):
    parser = subparsers.add_parser(
        "render-bench", help="measure render throughput and the accuracy-versus-time curve",
        description="Measure Mitsuba's samples/s against the spp per mi.render call, and the "
                    "cross-check RMS against render time for several spp.")
    add_scene_argument(parser, default="scenes/paper_plane.xml")
    add_out_option(parser, COMMAND, "out/render_bench")
    parser.add_argument("--per-call", default="4,8,12,16,24,36",
                        help="spp per mi.render call to time (comma-separated)")
    parser.add_argument("--throughput-spp", type=positive_int, default=48,
                        help="total spp of each throughput measurement (default 48)")
    parser.add_argument("--spp", default="8,16,24,36,48,64",
                        help="total spp of the accuracy curve (comma-separated)")
    add_define_option(parser)
    parser.add_argument("--variant", help="Mitsuba variant (default: automatic)")
    add_progress_option(parser)


def _int_list(text: str, option: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        values = []
    if not values or min(values) < 1:
        raise CLIError(f"{option} must be a comma-separated list of positive integers, got {text!r}")
    return values


def measure_throughput(mscene, mi, spec, per_call_list, total_spp, log):
    """``[{spp_per_call, calls, seconds, samples_per_second}]`` for the left view."""
    import numpy as np

    from synth.integrator import render_integrator
    from synth.mitsuba_setup import render

    w, h = spec.size
    integrator = render_integrator(mi, mscene)
    np.array(render(mi, mscene, sensor=0, spp=1, seed=12345,  # JIT compilation, not timed
                    integrator=integrator))
    rows = []
    for per_call in per_call_list:
        calls = max(1, -(-total_spp // per_call))
        start = time.perf_counter()
        for k in range(calls):
            np.array(render(mi, mscene, sensor=0, spp=per_call, seed=k, integrator=integrator))
        seconds = time.perf_counter() - start
        rows.append({"spp_per_call": per_call, "calls": calls, "seconds": seconds,
                     "samples_per_call": w * h * per_call,
                     "samples_per_second": w * h * per_call * calls / seconds})
        log(f"  {per_call:3d} spp per call x {calls}: {rows[-1]['samples_per_second'] / 1e6:.2f} "
            f"M samples/s")
    return rows


def measure_side_by_side(mscene, mi, spec, spp: int, log) -> dict:
    """Both views at ``spp``: one ``mi.render`` call per view, then the pass plan, timed in the
    same process one after the other (render seconds, both views)."""
    import numpy as np

    from synth.integrator import render_integrator
    from synth.mitsuba_setup import render
    from synth.render import pass_plan

    w, h = spec.size
    integrator = render_integrator(mi, mscene)
    plan = pass_plan(spp, w * h)
    timings = {}
    for label, passes in (("one_call", [spp]), ("passes", plan)):
        start = time.perf_counter()
        for view in (0, 1):
            for k, pass_spp in enumerate(passes):
                np.array(render(mi, mscene, sensor=view, spp=pass_spp, seed=view + 2 * k,
                                integrator=integrator))
        timings[label] = time.perf_counter() - start
    speedup = timings["one_call"] / timings["passes"]
    log(f"  {spp} spp, both views: one call {timings['one_call']:.1f} s, passes "
        f"{'+'.join(map(str, plan))} {timings['passes']:.1f} s: {speedup:.2f}x")
    return {"spp": spp, "passes": plan, "seconds": timings, "speedup": speedup}


def measure_accuracy(spec, spp_list, variant, log):
    """``[{spp, seconds, crosscheck…}]``: both views rendered in passes, detected, compared."""
    from eval.run.inputs import RunInputs
    from eval.run.pipeline import crosscheck_stage
    from measure import detect_targets
    from synth.render import render_stereo

    rows = []
    for spp in spp_list:
        left, right, info = render_stereo(spec, spp=spp, variant=variant, progress=False)
        seconds = info["seconds"]["left"] + info["seconds"]["right"]
        inputs = RunInputs(spec.path, spec.rig, spec.has_port, spec.targets, spec.target_ids,
                           spec.target_radius, left, right, spec.params, info["variant"], spp,
                           seconds, spec.seed, {}, spec.target_normals)
        crosscheck = crosscheck_stage(inputs, {"left": detect_targets(left),
                                               "right": detect_targets(right)})[3]
        rows.append({"spp": spp, "passes": info["passes"]["left"], "seconds": seconds,
                     "samples_per_second": info["samples_per_second"],
                     "rms_px": crosscheck["rms_px"], "max_px": crosscheck["max_px"],
                     "rms_px_outline": crosscheck["rms_px_outline"],
                     "max_px_outline": crosscheck["max_px_outline"],
                     "associated": crosscheck["left"]["associated"]
                     + crosscheck["right"]["associated"]})
        log(f"  {spp:3d} spp ({'+'.join(map(str, info['passes']['left']))}): {seconds:.1f} s, "
            f"cross-check RMS {crosscheck['rms_px']:.4f} px, outline {crosscheck['rms_px_outline']:.4f} px")
    return rows


def curve_figure(path, throughput, accuracy, title):
    """Two panels: samples/s against spp per call; cross-check RMS against render seconds."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    a, b = fig.subplots(1, 2)
    a.plot([r["spp_per_call"] for r in throughput],
           [r["samples_per_second"] / 1e6 for r in throughput], "o-")
    a.set_xlabel("spp per mi.render call (left view)")
    a.set_ylabel("M samples / s")
    a.set_title("Throughput against the wavefront size")
    a.grid(alpha=0.3)
    seconds = [r["seconds"] for r in accuracy]
    b.plot(seconds, [r["rms_px"] for r in accuracy], "o-", label="against the centre's pixel")
    b.plot(seconds, [r["rms_px_outline"] for r in accuracy], "s-",
           label="against the outline centroid")
    for r in accuracy:
        b.annotate(f"{r['spp']} spp", (r["seconds"], r["rms_px_outline"]),
                   textcoords="offset points", xytext=(4, -12), fontsize=8)
    b.set_xlabel("render time, both views (s)")
    b.set_ylabel("cross-check RMS (px)")
    b.set_title("Accuracy against time (passes)")
    b.grid(alpha=0.3)
    b.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=110)


def main(args) -> int:
    from synth.fileio import OutputDir, atomic_write_json
    from synth.provenance import package_versions
    from synth.render import MAX_SAMPLES_PER_CALL, load_mitsuba_scene
    from synth.scene import load_scene, parse_defines

    log = (lambda text: None) if args.no_progress else (
        lambda text: print(text, file=sys.stderr, flush=True))
    per_call = _int_list(args.per_call, "--per-call")
    spp_list = _int_list(args.spp, "--spp")
    output = OutputDir(args.out, COMMAND).claim()
    spec = load_scene(args.scene, parse_defines(args.defines))
    mscene, mi, variant = load_mitsuba_scene(spec, args.variant)
    w, h = spec.size
    log(f"throughput, left view, {w}x{h} px, {variant}:")
    throughput = measure_throughput(mscene, mi, spec, per_call, args.throughput_spp, log)
    log(f"side by side at the scene's {spec.spp} spp:")
    side_by_side = measure_side_by_side(mscene, mi, spec, spec.spp, log)
    log("accuracy against time, both views, rendered in passes:")
    accuracy = measure_accuracy(spec, spp_list, variant, log)
    result = {"scene": args.scene, "size": [w, h], "variant": variant, "cpu_count": os.cpu_count(),
              "max_samples_per_call": MAX_SAMPLES_PER_CALL, "throughput": throughput,
              "side_by_side": side_by_side,
              "accuracy": accuracy, "versions": package_versions()}
    with output.staged() as tmp:
        atomic_write_json(os.path.join(tmp, "render_bench.json"), result)
        curve_figure(os.path.join(tmp, "render_curve.png"), throughput, accuracy,
                     f"{os.path.basename(args.scene)}, {w}x{h} px, {variant}, "
                     f"{os.cpu_count()} cores")
    print(f"wrote {output.path}")
    return 0
