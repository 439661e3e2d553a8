"""The output directory of ``python -m eval sweep``, updated in place cell by cell.

:class:`SweepDir` guards and writes ``DIR``: it must not exist, be empty, or be an earlier output
of ``eval sweep`` (its marker) holding only what a sweep writes; every file is written
atomically (temporary file + rename); ``DIR/sweep.json`` records the spec's hash, the runs and
their ids; a finished cell is ``DIR/cells/<key>.json`` (its record) and a line of
``DIR/completions.log``.
"""

from __future__ import annotations

import json
import os
import re

from eval.cli import CLIError

COMMAND = "eval sweep"
#: What a sweep writes at the top of its directory (anything else makes it foreign).
TOP_LEVEL = ("sweep.json", "spec.toml", "cells", "files", "figures", "results.parquet",
             "results.csv", "completions.log", ".sweep.lock")
_KEY = re.compile(r"^[0-9a-f]{20}$")


class SweepDir:
    """The output directory of a sweep (see module docs): checked, locked, updated in place."""

    def __init__(self, path):
        self.display = os.fspath(path)
        self.path = os.path.abspath(self.display)
        self.cells = os.path.join(self.path, "cells")
        self._lock = None

    def _refuse(self, why: str):
        raise CLIError(f"--out {self.display} {why}")

    def check(self) -> dict | None:
        """The rule (no writes): returns the earlier sweep's ``sweep.json`` or None."""
        from synth.infra.fileio import directory_problem, read_marker

        path = self.path
        problem = directory_problem(path)
        if problem:
            self._refuse(problem)
        if os.path.isdir(path) and not os.access(path, os.W_OK | os.X_OK):
            self._refuse(f"cannot be written: {path} is not writable")  # updated in place
        if not os.path.isdir(path) or not os.listdir(path):
            return None
        marker = read_marker(path)
        if marker is None or marker.get("command") != COMMAND:
            self._refuse("exists and holds files this command did not write")
        foreign = [name for name in self._entries() if not self._ours(name)]
        if foreign:
            self._refuse(f"exists and holds files this command did not write ({foreign[0]})")
        try:
            with open(os.path.join(path, "sweep.json"), encoding="utf-8") as handle:
                return json.load(handle)
        except (OSError, ValueError):
            return {}

    def _entries(self):
        for root, dirs, files in os.walk(self.path):
            rel = os.path.relpath(root, self.path)
            for name in dirs + files:
                yield os.path.normpath(os.path.join(rel, name))

    @staticmethod
    def _ours(rel: str) -> bool:
        from synth.infra.fileio import MARKER_NAME, TEMPORARY_FILE

        parts = rel.split(os.sep)
        top = parts[0]
        if len(parts) == 1:
            return top in TOP_LEVEL or top == MARKER_NAME or bool(TEMPORARY_FILE.match(top))
        if top == "cells":
            name = parts[1]
            return len(parts) == 2 and (bool(_KEY.match(name[:-5])) and name.endswith(".json")
                                        or bool(TEMPORARY_FILE.match(name)))
        if top == "files":
            return bool(_KEY.match(parts[1])) and len(parts) <= 3
        if top == "figures":
            return len(parts) == 2
        return False

    def open(self, spec, allow_changed: bool, previous: dict | None) -> None:
        """Create or reuse the directory for ``spec``; lock it against a second sweep."""
        from synth.infra.fileio import claim_in_place

        if previous and previous.get("spec_hash") not in (None, spec.spec_hash()):
            if not allow_changed:
                self._refuse(f"holds a sweep of another spec ({previous.get('spec_path', '?')}, "
                             f"hash {str(previous.get('spec_hash'))[:12]}); use "
                             f"--allow-changed-spec to reuse the cells both specs share")
        os.makedirs(self.cells, exist_ok=True)
        self._lock = claim_in_place(
            self.path, ".sweep.lock", self._refuse, (self.path, self.cells),
            {"command": COMMAND, "files": sorted(TOP_LEVEL),
             "note": "updated in place cell by cell (eval sweep)"}, spec.text)

    def write_state(self, spec, runs: list, figures: dict | None = None) -> None:
        """``sweep.json``: the spec, the runs and ``figures`` (``{"digest", "files"}``: what the
        figures were drawn from, :meth:`drawn_figures`; None keeps the earlier entry, which
        holds its own digest)."""
        from synth.infra.fileio import atomic_write_json

        if figures is None:
            try:
                with open(os.path.join(self.path, "sweep.json"), encoding="utf-8") as handle:
                    figures = json.load(handle).get("figures")
            except (OSError, ValueError, AttributeError):
                figures = None

        atomic_write_json(os.path.join(self.path, "sweep.json"), {
            "spec_path": spec.path, "spec_hash": spec.spec_hash(), "name": spec.name,
            "cells": len(spec.cells), "spec": spec.canonical(), "runs": runs,
            **({"figures": figures} if figures is not None else {})})

    def drawn_figures(self, digest: str) -> list | None:
        """The figure paths of an earlier run that drew them from the same table (``digest``),
        when every one is still there; None otherwise (they are drawn again)."""
        try:
            with open(os.path.join(self.path, "sweep.json"), encoding="utf-8") as handle:
                figures = json.load(handle).get("figures") or {}
        except (OSError, ValueError):
            return None
        files = figures.get("files")
        if figures.get("digest") != digest or not isinstance(files, list):
            return None
        paths = [os.path.join(self.path, "figures", str(name)) for name in files]
        return paths if all(os.path.isfile(p) for p in paths) else None

    def previous_runs(self) -> list:
        try:
            with open(os.path.join(self.path, "sweep.json"), encoding="utf-8") as handle:
                return list(json.load(handle).get("runs", []))
        except (OSError, ValueError):
            return []

    def load_records(self, keys) -> dict:
        """The finished cells among ``keys``: ``{key: record}`` (unreadable files are ignored:
        those cells run again)."""
        records = {}
        for key in keys:
            try:
                with open(os.path.join(self.cells, f"{key}.json"), encoding="utf-8") as handle:
                    record = json.load(handle)
            except (OSError, ValueError):
                continue
            if record.get("key") == key:
                records[key] = record
        return records

    def write_record(self, record: dict, files: dict, durable: bool = False) -> None:
        from synth.infra.fileio import atomic_write_bytes

        for name, data in (files or {}).items():
            folder = os.path.join(self.path, "files", record["key"])
            os.makedirs(folder, exist_ok=True)
            atomic_write_bytes(os.path.join(folder, name), data)
        text = json.dumps(record, allow_nan=False, separators=(",", ":"))
        _write_atomic(os.path.join(self.cells, f"{record['key']}.json"), text.encode("utf-8"),
                      durable)
        with open(os.path.join(self.path, "completions.log"), "a", encoding="utf-8") as handle:
            handle.write(f"{record['key']} {record['run_id']}\n")


def _write_atomic(path: str, data: bytes, durable: bool) -> None:
    """Temporary file + rename: whole or absent after a ``kill -9``; ``durable`` also fsyncs
    (a cell file need not survive a power cut: its cell would simply run again)."""
    if durable:
        from synth.infra.fileio import atomic_write_bytes

        atomic_write_bytes(path, data)
        return
    directory, name = os.path.split(path)
    tmp = os.path.join(directory, f".{name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as handle:
        handle.write(data)
    os.chmod(tmp, 0o644)
    os.replace(tmp, path)


__all__ = ["COMMAND", "SweepDir", "TOP_LEVEL"]
