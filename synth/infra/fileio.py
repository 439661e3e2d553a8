"""Atomic output for the whole project: a result appears whole or not at all, and no command ever
deletes or changes a file it did not write.

Two tools:

* :class:`OutputDir` — a command's output directory. :meth:`OutputDir.claim` checks the ``--out``
  rule *before* any expensive work: the directory may be replaced only if it does not exist, is
  empty, or is an earlier output of the same command — it holds the marker file
  :data:`MARKER_NAME` that this module wrote (project name, schema version, command, the files
  written with their sizes and SHA-256) and nothing else. Anything else is refused with
  ``--out DIR exists and holds files this command did not write``. :meth:`OutputDir.staged` then
  yields a staging directory beside the output (``.NAME.staging-PID-XXXX``), writes the marker
  into it and renames it into place; on an exception the staging directory is removed and the
  output is left as it was. Staging and trash directories left by a process that died (``kill -9``)
  are removed by the next claim of the same output: their names carry the owner's PID. Files of
  an earlier output that changed since they were written (edited by hand) are copied to
  ``NAME.edited/`` beside it before it is replaced, and a ``note:`` line says so.
  :meth:`OutputDir.damage` says whether every file written is still whole (a command that skips
  an up-to-date output skips only a whole one).
* :func:`atomic_write_bytes` / :func:`atomic_write_text` — one file, written to a temporary file
  beside it and renamed into place; :func:`atomic_create_bytes` — the same, but only where no
  file is (it never replaces one).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path

#: The marker file of every output directory this project writes.
MARKER_NAME = ".refractive-stereo-output.json"
#: The project name and the marker's schema version written into it.
PROJECT_NAME = "refractive-stereo"
MARKER_SCHEMA = 1

_STAGING = re.compile(r"^\.(?P<name>.+)\.(?P<kind>staging|trash)-(?P<pid>\d+)-[A-Za-z0-9_]+$")


#: Name of a temporary file of :func:`atomic_write_bytes` (left behind only by a killed process).
TEMPORARY_FILE = re.compile(r"^\..+\.tmp$")


class OutputError(ValueError):
    """An output path that cannot be used (a user error: the CLIs print it and exit with 2)."""


def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def remove_stale_staging(out_dir) -> list[str]:
    """Remove staging/trash directories of ``out_dir`` whose owner process is dead; return them."""
    out_dir = os.path.abspath(os.fspath(out_dir))
    parent, name = os.path.split(out_dir)
    removed = []
    try:
        entries = os.listdir(parent)
    except OSError:
        return removed
    for entry in entries:
        match = _STAGING.match(entry)
        if not match or match.group("name") != name:
            continue
        pid = int(match.group("pid"))
        if pid == os.getpid() or _pid_alive(pid):
            continue
        shutil.rmtree(os.path.join(parent, entry), ignore_errors=True)
        removed.append(entry)
    return removed


def read_marker(out_dir) -> dict | None:
    """The marker of an output directory written by this project, or None."""
    path = os.path.join(os.fspath(out_dir), MARKER_NAME)
    try:
        with open(path, encoding="utf-8") as handle:
            marker = json.load(handle)
    except (OSError, ValueError):
        return None
    if not isinstance(marker, dict) or marker.get("project") != PROJECT_NAME:
        return None
    return marker


def _walk_files(directory: str) -> set[str]:
    """Every file and directory below ``directory``, as paths relative to it."""
    found = set()
    for root, dirs, files in os.walk(directory):
        rel = os.path.relpath(root, directory)
        for item in dirs + files:
            found.add(os.path.normpath(os.path.join(rel, item)))
    return found


def directory_problem(path) -> str | None:
    """Why the output directory ``path`` cannot be created or written (``"exists and is not a
    directory"``, ``"cannot be created: … is not a directory / is not writable"``), or None:
    the nearest existing ancestor must be a writable directory that takes a new folder (one is
    made and removed there: root passes ``os.access`` on ``/proc``)."""
    if os.path.lexists(path) and not os.path.isdir(path):
        return "exists and is not a directory"
    probe = os.path.dirname(path)
    while not os.path.exists(probe):
        probe = os.path.dirname(probe)
    if not os.path.isdir(probe):
        return f"cannot be created: {probe} is not a directory"
    if not os.access(probe, os.W_OK | os.X_OK):
        return f"cannot be created: {probe} is not writable"
    try:  # access() says yes to root on a file system that takes no folder (/proc, read-only)
        os.rmdir(tempfile.mkdtemp(prefix=".refractive-stereo-probe-", dir=probe))
    except OSError as exc:
        return f"cannot be created in {probe} ({exc.strerror or exc})"
    return None


class OutputDir:
    """The output directory of one command (``command`` e.g. ``"eval run"``). See module docs."""

    def __init__(self, path, command: str, option: str = "--out"):
        if not os.fspath(path).strip():
            raise OutputError(f"{option}: the path is empty: give a directory")
        self.path = os.path.abspath(os.fspath(path))
        self.display = os.fspath(path)
        self.command = command
        self.option = option

    # -- the rule -------------------------------------------------------------------------------
    def _refuse(self, why: str):
        raise OutputError(f"{self.option} {self.display} {why}")

    def check(self) -> None:
        """Raise :class:`OutputError` unless this command may write (or replace) the directory."""
        path = self.path
        problem = directory_problem(path)
        if problem:
            self._refuse(problem)
        if not os.path.isdir(path):
            return
        try:
            contents = os.listdir(path)
        except OSError as exc:
            self._refuse(f"cannot be read ({exc.strerror or exc})")
        if not contents:
            return
        marker = read_marker(path)
        if marker is None or marker.get("command") != self.command:
            self._refuse("exists and holds files this command did not write")
        written = {os.path.normpath(f) for f in marker.get("files", [])} | {MARKER_NAME}
        if not _walk_files(path) <= written:
            self._refuse("exists and holds files this command did not write")
        parent = os.path.dirname(path)
        if not os.access(parent, os.W_OK | os.X_OK):
            self._refuse(f"cannot be replaced: {parent} is not writable")

    def claim(self) -> OutputDir:
        """Check the rule and clear dead processes' staging directories; returns ``self``."""
        self.check()
        if os.path.isdir(os.path.dirname(self.path)):
            remove_stale_staging(self.path)
        return self

    def exists_as_output(self) -> bool:
        """Whether the directory is an earlier output of this command."""
        marker = read_marker(self.path)
        return marker is not None and marker.get("command") == self.command

    def damage(self) -> str | None:
        """None when every file this output's marker lists is as it was written (its size and
        SHA-256); otherwise what is wrong, in words (``left.png is missing``, ``left.png changed
        since it was written``). An output is up to date only when whole."""
        marker = read_marker(self.path) or {}
        digests = marker.get("sha256")
        if not isinstance(digests, dict):
            return "its marker holds no record of the files' contents (an older output)"
        for name, entry in sorted(digests.items()):
            path = os.path.join(self.path, name)
            if not os.path.isfile(path):
                return f"{name} is missing"
            size, digest = entry
            if os.path.getsize(path) != size or file_sha256(path) != digest:
                return f"{name} changed since it was written"
        return None

    # -- writing --------------------------------------------------------------------------------
    @contextmanager
    def staged(self, extra: dict | None = None):
        """Yield a staging directory; on success it becomes the output (with the marker).

        ``extra`` is stored in the marker (e.g. a request key). The rule is checked again just
        before the rename, so a file that appeared meanwhile is never deleted; an interrupted
        command (:mod:`synth.infra.interrupt`, even if a library swallowed the interrupt) never
        renames its staging directory into place.
        """
        from synth.infra import interrupt

        self.claim()
        parent, name = os.path.split(self.path)
        try:
            os.makedirs(parent, exist_ok=True)
            tmp = tempfile.mkdtemp(prefix=f".{name}.staging-{os.getpid()}-", dir=parent)
        except OSError as exc:
            self._refuse(f"cannot be created ({exc.strerror or exc})")
        os.chmod(tmp, 0o755)
        try:
            yield tmp
            files = sorted(_walk_files(tmp))
            digests = {name: [os.path.getsize(os.path.join(tmp, name)),
                              file_sha256(os.path.join(tmp, name))]
                       for name in files if os.path.isfile(os.path.join(tmp, name))}
            marker = {"project": PROJECT_NAME, "schema": MARKER_SCHEMA, "command": self.command,
                      "files": files, "sha256": digests, **(extra or {})}
            with open(os.path.join(tmp, MARKER_NAME), "w", encoding="utf-8") as handle:
                json.dump(marker, handle, indent=1)
                handle.write("\n")
            interrupt.check()
            self.check()
            self._replace(tmp)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise

    def _replace(self, tmp: str) -> None:
        path = self.path
        parent, name = os.path.split(path)
        if not os.path.exists(path):
            os.rename(tmp, path)
            return
        if not os.listdir(path):
            os.rmdir(path)
            os.rename(tmp, path)
            return
        self._keep_edited()
        trash = tempfile.mkdtemp(prefix=f".{name}.trash-{os.getpid()}-", dir=parent)
        os.rename(path, os.path.join(trash, "old"))
        try:
            os.rename(tmp, path)
        except OSError:
            os.rename(os.path.join(trash, "old"), path)  # put the old output back
            shutil.rmtree(trash, ignore_errors=True)
            raise
        shutil.rmtree(trash, ignore_errors=True)


    def edited_files(self) -> list[str]:
        """The files of this earlier output that changed since this command wrote them (their
        size or SHA-256 differs from the marker's record; a missing file is not listed)."""
        digests = (read_marker(self.path) or {}).get("sha256")
        if not isinstance(digests, dict):
            return []
        out = []
        for name, (size, digest) in sorted(digests.items()):
            path = os.path.join(self.path, name)
            if os.path.isfile(path) and (os.path.getsize(path) != size
                                         or file_sha256(path) != digest):
                out.append(name)
        return out

    def _keep_edited(self) -> None:
        """Before an earlier output is replaced: its files that changed since they were
        written (edited by hand: notes in a report, a tuned calibration) are copied to
        ``NAME.edited/`` beside it (``NAME.edited-2/``, … when that exists) and a ``note:``
        line says where — nothing the user wrote is lost."""
        import sys

        edited = self.edited_files()
        if not edited:
            return
        parent, name = os.path.split(self.path)
        k, keep = 1, os.path.join(parent, f"{name}.edited")
        while os.path.lexists(keep):
            k += 1
            keep = os.path.join(parent, f"{name}.edited-{k}")
        for rel in edited:
            os.makedirs(os.path.dirname(os.path.join(keep, rel)), exist_ok=True)
            shutil.copy2(os.path.join(self.path, rel), os.path.join(keep, rel))
        print(f"note: {', '.join(edited)} in {self.display} changed since {self.command} wrote "
              f"{'it' if len(edited) == 1 else 'them'}: kept in {keep} before the output was "
              f"replaced", file=sys.stderr)


def file_sha256(path) -> str:
    """The SHA-256 of a file's bytes (hex), read in chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def atomic_write_bytes(path, data: bytes, mode: int = 0o644) -> Path:
    """Write ``data`` to a temporary file beside ``path``, then rename it into place."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, mode)  # mkstemp makes 0600; outputs are meant to be read
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return path


def atomic_create_bytes(path, data: bytes, mode: int = 0o644) -> Path:
    """Write ``data`` at ``path`` only if nothing is there: a temporary file beside it is
    hard-linked into place, which fails with ``FileExistsError`` when ``path`` exists (also one
    that appeared meanwhile) and so never replaces anything."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.link(tmp, path)
    finally:
        try:
            os.unlink(tmp)
        except OSError:
            pass
    return path


def atomic_write_text(path, text: str) -> Path:
    """:func:`atomic_write_bytes` of UTF-8 text."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path, value, **dump_args) -> Path:
    """:func:`atomic_write_text` of ``json.dumps(jsonable(value), indent=2)`` plus a newline
    (NaN is written as null: the file is strict JSON)."""
    return atomic_write_text(path, json.dumps(jsonable(value), indent=2, allow_nan=False,
                                              **dump_args) + "\n")


def jsonable(value):
    """Plain JSON types: dicts, lists, bools, ints, finite floats; NaN and ±inf become null;
    numpy scalars and arrays become Python numbers and lists; objects with ``to_json()`` (typed
    results) are converted."""
    import numpy as np

    if hasattr(value, "to_json"):
        return jsonable(value.to_json())
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if np.isfinite(value) else None
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    return value


def claim_in_place(path, lock_name: str, refuse, roots, marker: dict, spec_text: str,
                   token: str | None = None):
    """Take over a directory that a command updates in place (``eval sweep``, ``synth
    suite``): lock ``path/lock_name`` exclusively (``refuse(why)`` raises when another process
    holds it; ``token``, if given, is written into the lock file), remove the temporary files
    a killed run left in ``roots``, write the output ``marker`` (the project, schema and the
    given fields) and ``spec.toml`` (``spec_text``). Returns the open lock file: the lock lasts
    as long as it stays open."""
    import fcntl

    lock = open(os.path.join(path, lock_name), "a+", encoding="utf-8")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        lock.close()
        refuse(f"is being written by another {marker['command'].split()[-1]}")
    if token is not None:
        lock.seek(0)
        lock.truncate()
        lock.write(token + "\n")
        lock.flush()
    for root in roots:
        for name in os.listdir(root):
            if TEMPORARY_FILE.match(name):
                os.unlink(os.path.join(root, name))
    atomic_write_json(os.path.join(path, MARKER_NAME),
                      {"project": PROJECT_NAME, "schema": MARKER_SCHEMA, **marker})
    atomic_write_text(os.path.join(path, "spec.toml"), spec_text)
    return lock


def check_file_output(path, option: str, may_replace=None) -> str:
    """Check a single output file before the work: its directory exists and is writable, and an
    existing file is replaced only if ``may_replace(path)`` says it is ours. Returns the path."""
    path = os.fspath(path)
    if not path.strip():
        raise OutputError(f"{option}: the path is empty: give a file name")
    full = os.path.abspath(path)
    if os.path.isdir(full):
        raise OutputError(f"{option} {path} is a directory")
    parent = os.path.dirname(full)
    if not os.path.isdir(parent):
        raise OutputError(f"{option} {path}: directory {os.path.dirname(path) or '.'} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{option} {path}: directory {os.path.dirname(path) or '.'} is not writable")
    try:  # access() says yes to root on a file system that takes no file (/proc, read-only)
        handle, probe = tempfile.mkstemp(prefix=".refractive-stereo-probe-", dir=parent)
        os.close(handle)
        os.unlink(probe)
    except OSError as exc:
        raise OutputError(f"{option} {path}: no file can be written in "
                          f"{os.path.dirname(path) or '.'} ({exc.strerror or exc})") from None
    if os.path.lexists(full) and may_replace is not None and not may_replace(full):
        raise OutputError(f"{option} {path} exists and is not a file this command wrote")
    return path


__all__ = ["MARKER_NAME", "OutputDir", "OutputError", "TEMPORARY_FILE", "atomic_create_bytes",
           "atomic_write_bytes", "atomic_write_json", "atomic_write_text", "check_file_output",
           "claim_in_place", "file_sha256", "jsonable", "read_marker", "remove_stale_staging"]
