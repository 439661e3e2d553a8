"""``python -m eval render-bench``: how fast the renderer is, and what its samples buy.

Two measurements on one scene (default ``scenes/paper_plane.xml`` at full size), wall clock,
reading the image back (Dr.Jit is lazy: the work happens when the result is read):

1. **Throughput against the wavefront size**: the left view rendered with ``--per-call`` spp in
   each ``mi.render`` call, as many calls as reach ``--throughput-spp`` samples per pixel;
   samples per second for each.
2. **Side by side**: both views at the scene's spp, one ``mi.render`` call per view against
   the pass plan, timed one after the other in the same process.
3. **Adaptive against full film**, side by side: both views rendered on the full film at
   ``--full-film-spp`` (default 36), adaptively (:func:`synth.rendering.render.render_view_counted`: a
   pilot, then the samples only where it saw light) at the same spp and adaptively at the
   scene's spp, one after the other in the same process, each with its render seconds,
   samples, lit fraction and cross-check.
4. **Accuracy against time**: both views rendered on the full film with the project's pass plan
   (:func:`synth.rendering.render.pass_plan`) at each total spp of ``--spp``, and adaptively at each spp
   of ``--adaptive-spp``, the targets detected and compared with the Fermat simulator (against
   each centre's pixel and against the outline centroid); cross-check RMS (px) against render
   seconds, both curves in one figure.

``--parts`` chooses which of ``throughput``, ``passes`` (2), ``adaptive`` (3), ``curve`` (the
full-film curve of 4) and ``adaptive-curve`` run (default: all).

Writes ``DIR/render_bench.json`` and ``DIR/render_curve.png`` (``--out``, the project's output
rule). Speeds are measured here, never in tests.
"""

from __future__ import annotations

import os
import sys
import time

from eval.cli import CLIError, positive_int
from synth.infra.cli import add_define_option, add_out_option, add_progress_option, add_scene_argument

COMMAND = "eval render-bench"
#: The measurements ``--parts`` can choose.
PARTS = ("throughput", "passes", "adaptive", "curve", "adaptive-curve")


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
                        help="total spp of the full-film accuracy curve (comma-separated)")
    parser.add_argument("--adaptive-spp", default="16,36,64,100,144",
                        help="spp on the lit pixels of the adaptive accuracy curve "
                             "(comma-separated)")
    parser.add_argument("--full-film-spp", type=positive_int, default=36,
                        help="spp of the full-film render of the side by side (default 36, the "
                             "default before adaptive rendering)")
    parser.add_argument("--parts", default=",".join(PARTS),
                        help=f"what to measure (comma-separated, default all): {', '.join(PARTS)}")
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

    from synth.rendering.integrator import render_integrator
    from synth.rendering.mitsuba_setup import render

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

    from synth.rendering.integrator import render_integrator
    from synth.rendering.mitsuba_setup import render
    from synth.rendering.render import pass_plan

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


def measure_accuracy(spec, spp_list, variant, log, adaptive: bool = False):
    """``[{spp, seconds, crosscheck…}]``: both views rendered (on the full film in passes, or
    ``adaptive``), detected, compared."""
    from eval.run.inputs import RunInputs
    from eval.run.pipeline import crosscheck_stage
    from measure import detect_targets
    from measure.images.detect import FLOOR_FRACTION
    from synth.rendering.render import render_stereo

    rows = []
    for spp in spp_list:
        left, right, info = render_stereo(spec, spp=spp, variant=variant, progress=False,
                                          adaptive=adaptive)
        seconds = info["seconds"]["left"] + info["seconds"]["right"]
        views = info["render"]
        inputs = RunInputs(spec.path, spec.rig, spec.has_port, spec.targets, spec.target_ids,
                           spec.target_radius, left, right, spec.params, info["variant"], spp,
                           seconds, spec.seed, {}, spec.target_normals)
        crosscheck = crosscheck_stage(inputs, {
            view: detect_targets(image, floor_fraction=FLOOR_FRACTION)
            for view, image in (("left", left), ("right", right))})[3]
        rows.append({"spp": spp, "adaptive": adaptive, "mode": views["left"]["mode"],
                     "passes": info["passes"]["left"], "seconds": seconds,
                     "samples": views["left"]["samples"] + views["right"]["samples"],
                     "lit_fraction": [views[v]["lit_fraction"] for v in ("left", "right")],
                     "samples_per_second": info["samples_per_second"],
                     "rms_px": crosscheck["rms_px"], "max_px": crosscheck["max_px"],
                     "rms_px_outline": crosscheck["rms_px_outline"],
                     "max_px_outline": crosscheck["max_px_outline"],
                     "associated": crosscheck["left"]["associated"]
                     + crosscheck["right"]["associated"]})
        log(f"  {'adaptive' if adaptive else 'full film'} {spp:3d} spp "
            f"({'+'.join(map(str, info['passes']['left']))}): {seconds:.1f} s, "
            f"{rows[-1]['samples'] / 1e6:.1f} M samples, cross-check RMS "
            f"{crosscheck['rms_px']:.4f} px, outline {crosscheck['rms_px_outline']:.4f} px, "
            f"{rows[-1]['associated']} targets")
    return rows


def measure_adaptive(spec, variant, log, full_spp: int) -> dict:
    """Both views on the full film at ``full_spp``, adaptively at the same spp and adaptively
    at the scene's spp, one after the other in the same process."""
    full = measure_accuracy(spec, [full_spp], variant, log)[0]
    same = measure_accuracy(spec, [full_spp], variant, log, True)[0]
    scene = (same if spec.spp == full_spp else
             measure_accuracy(spec, [spec.spp], variant, log, True)[0])
    result = {"full_film": full, "adaptive_same_spp": same, "adaptive_scene_spp": scene,
              "speedup_same_spp": full["seconds"] / same["seconds"],
              "speedup_scene_spp": full["seconds"] / scene["seconds"]}
    log(f"  full film {full_spp} spp {full['seconds']:.1f} s, RMS {full['rms_px']:.4f} px; "
        f"adaptive {full_spp} spp {same['seconds']:.1f} s ({result['speedup_same_spp']:.1f}x), "
        f"RMS {same['rms_px']:.4f} px; adaptive {spec.spp} spp {scene['seconds']:.1f} s "
        f"({result['speedup_scene_spp']:.1f}x), RMS {scene['rms_px']:.4f} px")
    return result


def _throughput_panel(a, throughput) -> None:
    a.plot([r["spp_per_call"] for r in throughput],
           [r["samples_per_second"] / 1e6 for r in throughput], "o-")
    a.set_xlabel("spp per mi.render call (left view)")
    a.set_ylabel("M samples / s")
    a.set_title("Throughput against the wavefront size")
    a.grid(alpha=0.3)


def curve_figure(path, throughput, accuracy, title, adaptive=()):
    """Two panels: samples/s against spp per call; cross-check RMS against render seconds
    (full film and adaptive)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11 if throughput else 6.5, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    from matplotlib.ticker import FormatStrFormatter, NullFormatter

    a, b = fig.subplots(1, 2) if throughput else (None, fig.subplots(1, 1))
    all_seconds = [r["seconds"] for r in (*accuracy, *adaptive)] or [1.0]
    if a is not None:
        _throughput_panel(a, throughput)
    for rows, name, marks in ((accuracy, "full film", ("o-", "s-")),
                              (adaptive, "adaptive", ("o--", "s--"))):
        if not rows:
            continue
        seconds = [r["seconds"] for r in rows]
        b.plot(seconds, [r["rms_px"] for r in rows], marks[0],
               label=f"{name}: against the centre's pixel")
        b.plot(seconds, [r["rms_px_outline"] for r in rows], marks[1],
               label=f"{name}: against the outline centroid")
        for r in rows:
            b.annotate(f"{r['spp']} spp", (r["seconds"], r["rms_px_outline"]),
                       textcoords="offset points", xytext=(4, -12), fontsize=8)
    b.set_xscale("log")
    b.xaxis.set_major_formatter(FormatStrFormatter("%g"))
    b.xaxis.set_minor_formatter(NullFormatter())
    b.set_xticks([t for t in (1, 2, 3, 5, 10, 20, 30, 50, 100, 200, 500)
                  if 0.7 * min(all_seconds) <= t <= 1.4 * max(all_seconds)] or [1])
    b.set_xlabel("render time, both views (s)")
    b.set_ylabel("cross-check RMS (px)")
    b.set_title("Accuracy against time")
    b.grid(alpha=0.3)
    if b.get_legend_handles_labels()[1]:  # no accuracy curve measured (--parts): no legend
        b.legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=110)


def main(args) -> int:
    from synth.infra.fileio import OutputDir, atomic_write_json
    from synth.scene import load_scene, parse_defines

    log = (lambda text: None) if args.no_progress else (
        lambda text: print(text, file=sys.stderr, flush=True))
    per_call = _int_list(args.per_call, "--per-call")
    spp_list = _int_list(args.spp, "--spp")
    adaptive_spp = _int_list(args.adaptive_spp, "--adaptive-spp")
    parts = [p.strip() for p in args.parts.split(",") if p.strip()]
    unknown = sorted(set(parts) - set(PARTS))
    if unknown or not parts:
        raise CLIError(f"--parts: {', '.join(unknown) or 'nothing'} is not one of "
                       f"{', '.join(PARTS)}")
    output = OutputDir(args.out, COMMAND).claim()
    spec = load_scene(args.scene, parse_defines(args.defines)).require_two_cameras(
        "eval render-bench")
    result = _run_interruptibly(lambda: _measure(args, spec, parts, per_call, spp_list,
                                                 adaptive_spp, log))
    w, h = spec.size
    variant = result["variant"]
    with output.staged() as tmp:
        atomic_write_json(os.path.join(tmp, "render_bench.json"), result)
        curve_figure(os.path.join(tmp, "render_curve.png"), result["throughput"] or [],
                     result["accuracy"], f"{os.path.basename(args.scene)}, {w}x{h} px, "
                     f"{variant}, {os.cpu_count()} cores", result["accuracy_adaptive"])
    print(f"wrote {output.path}")
    return 0


def _run_interruptibly(work):
    """``work()`` on a daemon thread while the main thread waits in short joins: a Ctrl-C then
    ends the command at once — one line ``error: interrupted``, exit 130 — instead of after the
    Dr.Jit kernel under way (an adaptive render or a detection pass cannot be cut: 13–46 s).
    Nothing is written before the measurements end, so there is nothing to clean up; the
    thread's exceptions are raised here."""
    import threading

    from synth.infra.cli import EXIT_INTERRUPTED

    box = {}

    def target():
        try:
            box["value"] = work()
        except BaseException as exc:  # raised again in the main thread
            box["error"] = exc

    thread = threading.Thread(target=target, name="render-bench", daemon=True)
    thread.start()
    try:
        while thread.is_alive():
            thread.join(0.1)
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr, flush=True)
        os._exit(EXIT_INTERRUPTED)  # the render thread cannot be stopped from here
    if "error" in box:
        raise box["error"]
    return box["value"]


def _measure(args, spec, parts, per_call, spp_list, adaptive_spp, log) -> dict:
    """The measurements ``parts`` asks for, as ``render_bench.json`` holds them."""
    from synth.infra.provenance import package_versions
    from synth.rendering.render import MAX_SAMPLES_PER_CALL, load_mitsuba_scene

    mscene, mi, variant = load_mitsuba_scene(spec, args.variant)
    w, h = spec.size
    throughput = side_by_side = adaptive = None
    accuracy, adaptive_accuracy = [], []
    if "throughput" in parts:
        log(f"throughput, left view, {w}x{h} px, {variant}:")
        throughput = measure_throughput(mscene, mi, spec, per_call, args.throughput_spp, log)
    if "passes" in parts:
        log(f"one call against passes at the scene's {spec.spp} spp:")
        side_by_side = measure_side_by_side(mscene, mi, spec, spec.spp, log)
    if "adaptive" in parts:
        log(f"full film at {args.full_film_spp} spp against adaptive at the same and the scene's "
            f"{spec.spp} spp, both views:")
        adaptive = measure_adaptive(spec, variant, log, args.full_film_spp)
    if "curve" in parts:
        log("accuracy against time, both views, full film in passes:")
        accuracy = measure_accuracy(spec, spp_list, variant, log)
    if "adaptive-curve" in parts:
        log("accuracy against time, both views, adaptive:")
        adaptive_accuracy = measure_accuracy(spec, adaptive_spp, variant, log, True)
    result = {"scene": args.scene, "size": [w, h], "variant": variant, "cpu_count": os.cpu_count(),
              "load_average": list(os.getloadavg()),
              "max_samples_per_call": MAX_SAMPLES_PER_CALL, "throughput": throughput,
              "side_by_side": side_by_side, "adaptive_vs_full_film": adaptive,
              "accuracy": accuracy, "accuracy_adaptive": adaptive_accuracy,
              "versions": package_versions()}
    return result
