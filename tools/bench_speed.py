"""Benchmark what users wait for (issue 54; numbers for docs/speed.md; nothing asserted):
the start-up of each command line's ``--help``, ``import measure`` and the README's
``from measure import …``, and ``python -m eval run scenes/paper_plane.xml`` (and with
``--no-figures``) as a whole process.

Every measurement is a fresh process of the same Python (wall clock, from the start of the
process to its exit, and its CPU time: user + system of the process and its children), run in
the checkout given (``--repo``, default this one; repeat it to compare checkouts, e.g. one
before a change) with ``PYTHONPATH`` set to it: that checkout's code, not an installed one.
The cases (and checkouts) are interleaved round by round, so that a busy moment of a shared
machine hits all of them alike; the table gives the median and the range of ``--runs`` rounds
and, for the runs, the medians of the report's own timings. A case a checkout does not have
(an option it refuses: exit 2 with ``error:``) is left out of its rows. It prints the date, the
CPU model, the cores and the load average before and after.

    python tools/bench_speed.py [--runs 3] [--cases help,import,run,run-no-figures]
                                [--repo DIR ...] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SCENE = "scenes/paper_plane.xml"
#: name: (what it measures, the arguments of ``python``). ``{out}``: a fresh output folder.
CASES = {
    "eval-help": ("python -m eval --help", ["-m", "eval", "--help"]),
    "eval-run-help": ("python -m eval run --help", ["-m", "eval", "run", "--help"]),
    "eval-calibrate-help": ("python -m eval calibrate --help",
                            ["-m", "eval", "calibrate", "--help"]),
    "eval-run-bad-option": ("python -m eval run --no-such-option (exit 2)",
                            ["-m", "eval", "run", "--no-such-option"]),
    "synth-help": ("python -m synth --help", ["-m", "synth", "--help"]),
    "synth-render-help": ("python -m synth render --help", ["-m", "synth", "render", "--help"]),
    "import-measure": ('python -c "import measure"', ["-c", "import measure"]),
    "import-readme": ('python -c "from measure import Camera, FlatPort, StereoRig, triangulate"',
                      ["-c", "from measure import Camera, FlatPort, StereoRig, triangulate"]),
    "eval-run": (f"python -m eval run {SCENE}",
                 ["-m", "eval", "run", SCENE, "--out", "{out}", "--no-progress"]),
    "eval-run-no-figures": (f"python -m eval run {SCENE} --no-figures",
                            ["-m", "eval", "run", SCENE, "--out", "{out}", "--no-progress",
                             "--no-figures"]),
}
#: ``--cases`` groups.
GROUPS = {"help": ("eval-help", "eval-run-help", "eval-calibrate-help", "eval-run-bad-option",
                   "synth-help", "synth-render-help"),
          "import": ("import-measure", "import-readme"),
          "run": ("eval-run",), "run-no-figures": ("eval-run-no-figures",)}
#: The report's timings shown for a run.
RUN_TIMINGS = ("render", "report", "total")


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def load_average() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def measure_once(repo: Path, args: list) -> dict:
    """One fresh process: ``{"wall", "cpu", "code"}`` and, for a run, the report's timings."""
    out = Path(tempfile.mkdtemp(prefix="bench_speed_")) / "out"
    argv = [sys.executable] + [a.replace("{out}", str(out)) for a in args]
    env = dict(os.environ, PYTHONPATH=str(repo))
    cpu, start = children_cpu(), time.perf_counter()
    done = subprocess.run(argv, cwd=repo, env=env, stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True)
    result = {"wall": time.perf_counter() - start, "cpu": children_cpu() - cpu,
              "code": done.returncode}
    report = out / "report.json"
    if report.exists():
        timings = json.loads(report.read_text())["timings_s"]
        result.update({k: timings[k] for k in RUN_TIMINGS if k in timings})
    elif done.returncode not in (0, 2):
        raise SystemExit(f"{' '.join(argv)} failed ({done.returncode}): {done.stderr[-500:]}")
    shutil.rmtree(out.parent, ignore_errors=True)
    return result


def summary(values: list) -> str:
    return (f"{statistics.median(values):.2f}" if len(values) < 2 else
            f"{statistics.median(values):.2f} ({min(values):.2f}–{max(values):.2f})")


def table(cases: list, repos: list, samples: dict) -> str:
    """The markdown table: a row per case and checkout (the checkout's folder name)."""
    rows = ["| measured | checkout | wall s, median (range) | CPU s, median | report: render / "
            "report / total s |", "|---|---|---|---|---|"]
    for name in cases:
        for repo in repos:
            runs = samples[repo.name][name]
            if not runs:
                continue
            timings = " / ".join(f"{statistics.median(r[k] for r in runs):.2f}"
                                 for k in RUN_TIMINGS if all(k in r for r in runs))
            rows.append(f"| `{CASES[name][0]}` | {repo.name} | {summary([r['wall'] for r in runs])}"
                        f" | {statistics.median(r['cpu'] for r in runs):.2f} | {timings or '—'} |")
    return "\n".join(rows)


def selected(text: str) -> list:
    names = []
    for item in text.split(","):
        item = item.strip()
        if item in GROUPS:
            names += [n for n in GROUPS[item] if n not in names]
        elif item in CASES and item not in names:
            names.append(item)
        elif item not in CASES:
            raise SystemExit(f"error: unknown case {item!r} (choose from "
                             f"{', '.join(list(GROUPS) + list(CASES))})")
    return names


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=3, help="rounds (default 3)")
    p.add_argument("--cases", default="help,import,run,run-no-figures",
                   help="comma list of groups (help, import, run, run-no-figures) or cases")
    p.add_argument("--repo", type=Path, action="append",
                   help="a checkout to measure (default: this one); repeat to compare")
    p.add_argument("--json", type=Path, help="also write every sample to this file")
    args = p.parse_args(argv)
    cases = selected(args.cases)
    repos = [r.resolve() for r in (args.repo or [REPO])]
    print(f"{time.strftime('%Y-%m-%d %H:%M')}  {cpu_model()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}, checkouts "
          f"{', '.join(r.name for r in repos)}", flush=True)
    print(f"load average before: {load_average()}", flush=True)
    samples = {repo.name: {name: [] for name in cases} for repo in repos}
    for k in range(args.runs):
        for name in cases:
            for repo in repos:
                result = measure_once(repo, CASES[name][1])
                if result["code"] != 2 or name.endswith(("help", "bad-option")):
                    samples[repo.name][name].append(result)
        print(f"round {k + 1} of {args.runs} done; load average {load_average()}", flush=True)
    print(f"load average after: {load_average()}\n")
    print(table(cases, repos, samples))
    if args.json:
        args.json.write_text(json.dumps(samples, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
