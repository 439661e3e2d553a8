"""A pass of probes over every command and rig, as a new user would type them (issue 53): each
probe runs as its own process in a scratch folder, and is classified by what it did.

Fixtures are rendered small first (320 × 268 and 612 × 512 px, a few spp: a pair behind the
paper's port, three and four cameras, two housings, domes, one camera's photos, boards in air
and water, a sequence) and calibrated with the commands themselves. Then every probe runs with
``PYTHONPATH`` set to this checkout; the scratch tree (every fixture) is hashed before and after
each probe. A probe says what a careful program must do: ``ok`` (exit 0), ``fail`` (exit 1: a
result the run knows is wrong), ``bad`` (exit 2: one ``error:`` line, nothing written) or
``refuse`` (1 or 2: anything but success). The classes of finding:

* ``internal`` — exit 3 (``error: internal error:``) or a traceback;
* ``data loss`` — a file of the scratch tree whose content is gone (neither in place nor kept
  aside), but for unedited files of an earlier output (its marker records them) and sealed
  scene files not edited since;
* ``silent`` — exit 0 where the probe must not succeed (a silently wrong result);
* ``message`` — exit 2 without exactly one ``error:`` line last on stderr (``note:`` and
  ``warning:`` lines aside), or with a line of OpenCV, libpng or libjpeg before it;
* ``written`` — exit 2 and the ``--out`` folder or file exists though it did not before;
* ``refused`` — a non-zero exit where the probe expects success;
* ``exit code`` — a refusal with the other code (``bad`` exit 1, ``fail`` exit 2);
* ``timeout`` — a probe that ran past 10 minutes.

    python tools/probe_pass.py [--keep DIR] [--only SUBSTRING] [--real DIR] [--json FILE]

The fixtures and probes are listed in tools/probe_fixtures.py and tools/probe_list.py.

Prints one line per probe and a table of the counts; exit 0 when there is no finding.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from probe_fixtures import REPO, make  # tools/ is the script's folder, first on sys.path
from probe_list import PROBES


_HASHES: dict = {}
MARKER = ".refractive-stereo-output.json"


def _replaceable(path: Path, digest: str) -> bool:
    """Whether a command may replace the file: an unedited file of an earlier output (its
    folder's output marker records this content) or a sealed scene file not edited since."""
    if path.name == MARKER:
        return True
    if path.suffix == ".xml":
        text = path.read_text(errors="replace").rstrip("\n")
        head, _, last = text.rpartition("\n")
        if last.startswith("<!-- content sha256 "):
            return hashlib.sha256((head + "\n").encode()).hexdigest() == last.split()[3]
    for folder in path.parents:
        if (folder / MARKER).is_file():
            try:
                recorded = json.loads((folder / MARKER).read_text()).get("sha256", {})
            except (OSError, ValueError):
                return False
            entry = recorded.get(str(path.relative_to(folder)))
            return bool(entry) and entry[-1] == digest
    return False


def snapshot(root: Path) -> dict:
    """``{path: (sha256, replaceable)}`` of every file below ``root`` (a file's entry kept
    while its size, time and inode stay)."""
    out = {}
    for path in sorted(root.rglob("*")):
        if not path.is_file():
            continue
        stat = path.stat()
        key = (str(path), stat.st_size, stat.st_mtime_ns, stat.st_ino)
        if key not in _HASHES:
            digest = hashlib.sha256(path.read_bytes()).hexdigest()
            _HASHES[key] = (digest, _replaceable(path, digest))
        out[str(path.relative_to(root))] = _HASHES[key]
    return out


def lost(before: dict, after: dict) -> list:
    """The files of ``before`` whose content is nowhere in ``after`` (neither in place nor kept
    aside) and that no command may replace."""
    kept = {digest for digest, _ in after.values()}
    return sorted(k for k, (digest, replaceable) in before.items()
                  if digest not in kept and not replaceable)


def run(argv: list, cwd: Path, timeout: float = 600.0):
    """``(exit code, stdout, stderr, seconds)`` of ``python -m argv`` in ``cwd``."""
    env = dict(os.environ, PYTHONPATH=str(REPO), REFSTEREO_TRACEBACK="")
    start = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, "-m", *argv], cwd=cwd, env=env, text=True,
                              capture_output=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return 124, "", "timed out", time.perf_counter() - start
    return proc.returncode, proc.stdout, proc.stderr, time.perf_counter() - start


NOISE = ("[ WARN", "[ERROR", "libpng", "Premature end", "Corrupt JPEG", "Traceback")


def classify(expect: str, code: int, err: str, out_before: bool, out_after: bool,
             changed: list) -> list:
    """The findings of one probe (module docs), empty when it behaved."""
    found = []
    if code == 3 or "Traceback" in err or "internal error" in err:
        found.append("internal")
    if changed:
        found.append("data loss")
    lines = [line for line in err.strip().splitlines()
             if not line.startswith(("note:", "warning:"))]
    if code == 0 and expect in ("fail", "bad", "refuse"):
        found.append("silent")
    if code not in (0,) and expect == "ok":
        found.append("refused")
    if code == 2:
        errors = [line for line in lines if line.startswith("error:")]
        noisy = any(line.startswith(NOISE) for line in err.splitlines())
        if len(errors) != 1 or not lines or not lines[-1].startswith("error:") or noisy:
            found.append("message")
        if out_after and not out_before:
            found.append("written")
    if code not in (0, 124) and {"fail": 1, "bad": 2}.get(expect, code) != code:
        found.append("exit code")
    if code == 124:
        found.append("timeout")
    return found


def probe(number: int, expect: str, line: str, root: Path, real) -> dict:
    """Run one probe in ``root`` and classify it (module docs)."""
    out = f"probe_out_{number:03d}"
    argv = [a.replace("OUT", out).replace("REAL/", f"{real}/") for a in shlex.split(line)]
    out_paths = {root / a for a in argv if a.startswith(out)}
    before_out = any(p.exists() for p in out_paths)
    before = snapshot(root)
    code, stdout, err, seconds = run(argv, root)
    changed = lost(before, snapshot(root))
    found = classify(expect, code, err, before_out, any(p.exists() for p in out_paths),
                     changed)
    tail = (err.strip().splitlines() or stdout.strip().splitlines() or [""])[-1][:160]
    print(f"{number:3d} {expect:6s} exit {code:3d} {seconds:5.1f} s "
          f"{','.join(found) or 'ok':10s} {line[:80]} | {tail}", flush=True)
    return {"probe": number, "expect": expect, "command": line, "exit": code,
            "seconds": round(seconds, 2), "findings": found, "changed": changed,
            "stderr": err[-2000:], "stdout_tail": stdout[-500:]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--keep", default=None, help="the scratch folder (kept, and its "
                                                     "fixtures reused; default: a temporary "
                                                     "one, removed)")
    parser.add_argument("--only", default=None, help="run the probes whose command line holds "
                                                     "this text")
    parser.add_argument("--real", default=os.environ.get("REFSTEREO_REAL_PHOTOS", ""),
                        help="the shared real photos (default $REFSTEREO_REAL_PHOTOS, as the "
                             "tests read them; their probes skipped where absent)")
    parser.add_argument("--json", default=None, help="write every probe's result here")
    args = parser.parse_args(argv)
    root = Path(args.keep or tempfile.mkdtemp(prefix="probe-pass-")).resolve()
    root.mkdir(parents=True, exist_ok=True)
    real = Path(args.real).resolve() if args.real and Path(args.real).is_dir() else None
    make(root, run, real)
    for stale in root.glob("probe_out_*"):  # an earlier pass's outputs (--keep)
        shutil.rmtree(stale) if stale.is_dir() else stale.unlink()
    results, counts = [], {}
    for number, (expect, line) in enumerate(PROBES):
        if (args.only is not None and args.only not in line) or ("REAL/" in line and not real):
            continue
        results.append(probe(number, expect, line, root, real))
        for kind in results[-1]["findings"] or ["behaved"]:
            counts[kind] = counts.get(kind, 0) + 1
    print(f"\n{len(results)} probes: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    if args.json:
        Path(args.json).write_text(json.dumps({"root": str(root), "results": results,
                                               "counts": counts}, indent=1))
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    return 0 if set(counts) <= {"behaved"} else 1


if __name__ == "__main__":
    sys.exit(main())
