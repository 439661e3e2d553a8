"""Scenes that a suite generates from options instead of reading a committed scene file.

An item of a suite spec's ``scenes`` list may be a table of ``python -m synth scene`` options
(their long names with ``_`` for ``-``; lists for the options that take several numbers)::

    scenes = ["../scenes/small_grid.xml",                       # a scene file, or
              {name = "grid", layout = "grid", z = 1000, half_width = 300, spacing = 100},
              {name = "wavy", layout = "surface", surface = "wavy", water = "coastal"}]

and ``scene.<option>`` parameters of ``[fixed]``, ``[grid]``, ``[zip]``, ``[random]`` vary those
options (``"scene.water" = ["clear", "coastal"]``). Each distinct set of options is written by
the code of ``python -m synth scene`` (:func:`synth.commands.scene.main`, with its checks: an
option that does not apply to the layout is refused) into a temporary folder when the spec is
read — a bad option is a :class:`synth.infra.grid.SpecError` naming the scene and the option, before
anything is written — and later, atomically, into ``DIR/scenes/<name>_<hash>/`` of the suite
(:func:`write_generated`): ``scene.xml`` with its mesh and texture for surfaces. The hash of all
its files names the folder and is part of each entry's key, so that a change of the options or of
the scene code renders the entry again. ``seed`` and ``out`` are not options here (every entry
has its own seed; the suite places the files).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import os
import shutil
import tempfile
import uuid
from dataclasses import dataclass, replace

from synth.infra.grid import Scene, SpecError, read_scene

#: Options of ``python -m synth scene`` that a suite does not take (see the module docs).
EXCLUDED = ("out", "seed", "help")
#: The file name of a generated scene inside its folder.
SCENE_FILE = "scene.xml"


@dataclass(frozen=True)
class GeneratedScene:
    """A scene written from ``synth scene`` options: ``scene`` (its XML's bytes, hash, defaults,
    its name as ``label``; ``path`` where the suite writes it once :meth:`placed`), every file's
    bytes (``files``: the XML, the mesh, the texture), ``digest`` (SHA-256 over all the files)
    and ``folder`` (relative to the suite's directory)."""

    scene: Scene
    files: dict
    digest: str
    folder: str

    def placed(self, directory: str) -> Scene:
        """The scene with its path inside the suite's ``directory``."""
        return replace(self.scene, path=os.path.join(directory, self.folder, SCENE_FILE))


def _parser():
    """``(parser of python -m synth, the scene subparser's actions by dest)``."""
    from synth.infra.cli import Parser
    from synth.commands.scene import add_parser, main

    parser = Parser(prog="python -m synth")
    subparsers = parser.add_subparsers(dest="command", parser_class=Parser)
    add_parser(subparsers)
    subparsers.choices["scene"].set_defaults(_main=main)
    actions = {a.dest: a for a in subparsers.choices["scene"]._actions
               if a.option_strings and a.dest not in EXCLUDED}
    return parser, actions


def option_names() -> tuple:
    """The options a generated scene takes (``synth scene``'s, as ``dest`` names)."""
    return tuple(sorted(_parser()[1]))


def _argv(options: dict, actions: dict, base_dir: str, where: str) -> list:
    argv = []
    for key, value in options.items():
        action = actions.get(key)
        if key == "seed":
            raise SpecError(f"{where}: seed: every entry has its own seed, derived from the "
                            f"spec's seed (set seed = S at the top instead)")
        if key == "out":
            raise SpecError(f"{where}: out: the suite writes generated scenes into its "
                            f"DIR/scenes/")
        if action is None:
            raise SpecError(f"{where}: unknown option {key!r} (the options of python -m synth "
                            f"scene, with _ for -: {', '.join(sorted(actions))})")
        flag = next(s for s in action.option_strings if s.startswith("--"))
        if key == "mesh" and isinstance(value, str) and not os.path.isabs(value):
            value = os.path.join(base_dir, value)
        several = action.nargs not in (None, "?")
        if isinstance(action, argparse._AppendAction):
            if not (isinstance(value, list) and value and all(isinstance(v, list) for v in value)):
                raise SpecError(f"{where}: {key} = {value!r}: expected a list of "
                                f"[{', '.join(action.metavar or ('value',))}] lists")
            for item in value:
                argv += [flag, *(str(v) for v in item)]
        elif several:
            if not isinstance(value, list) or isinstance(value, bool):
                raise SpecError(f"{where}: {key} = {value!r}: expected a list of numbers")
            argv += [flag, *(str(v) for v in value)]
        else:
            if isinstance(value, (list, dict, bool)):
                raise SpecError(f"{where}: {key} = {value!r}: expected one number or string")
            argv += [flag, str(value)]
    return argv


def generate(name: str, options: dict, base_dir: str, label: str) -> GeneratedScene:
    """Write the scene of ``options`` with ``python -m synth scene``'s code into a temporary
    folder and keep its files' bytes; SpecError ``label: scene NAME: …`` on a bad option."""
    from synth.infra.cli import CLIError, one_line

    where = f"{label}: scene {name!r}"
    parser, actions = _parser()
    argv = _argv(options, actions, base_dir, where)
    tmp = tempfile.mkdtemp(prefix="refstereo-suite-scene-")
    try:
        path = os.path.join(tmp, SCENE_FILE)
        try:
            args = parser.parse_args(["scene", *argv, "--out", path])
            with contextlib.redirect_stdout(io.StringIO()):
                args._main(args)
        except (CLIError, ValueError) as exc:
            raise SpecError(f"{where}: {one_line(exc)}") from None
        files = {}
        for entry in sorted(os.listdir(tmp)):
            with open(os.path.join(tmp, entry), "rb") as handle:
                files[entry] = handle.read()
        scene = read_scene(path, tmp, label)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    digest = hashlib.sha256()
    for entry, data in files.items():
        digest.update(f"{entry}\0{hashlib.sha256(data).hexdigest()}\0".encode())
    digest = digest.hexdigest()
    stem = "".join(c if c.isalnum() or c in "_.-" else "_" for c in name)
    return GeneratedScene(replace(scene, label=name), files, digest,
                          f"scenes/{stem}_{digest[:12]}")


def write_generated(directory: str, generated: GeneratedScene) -> str:
    """Write ``generated``'s files into ``directory/<folder>/`` atomically (a staging folder
    renamed into place); nothing when the folder already holds exactly those files. Returns the
    scene file's path."""
    target = os.path.join(directory, generated.folder)
    path = os.path.join(target, SCENE_FILE)
    if _holds(target, generated.files):
        return path
    parent = os.path.dirname(target)
    os.makedirs(parent, exist_ok=True)
    tag = f"{os.getpid()}-{uuid.uuid4().hex[:8]}"
    base = os.path.basename(target)
    staging = os.path.join(parent, f".{base}.staging-{tag}")
    os.makedirs(staging)
    try:
        for name, data in generated.files.items():
            with open(os.path.join(staging, name), "wb") as handle:
                handle.write(data)
        if os.path.lexists(target):  # damaged: replaced whole
            trash = os.path.join(parent, f".{base}.trash-{tag}")
            os.rename(target, trash)
            shutil.rmtree(trash, ignore_errors=True)
        os.rename(staging, target)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return path


def _holds(folder: str, files: dict) -> bool:
    try:
        if sorted(os.listdir(folder)) != sorted(files):
            return False
        for name, data in files.items():
            with open(os.path.join(folder, name), "rb") as handle:
                if handle.read() != data:
                    return False
    except OSError:
        return False
    return True


__all__ = ["EXCLUDED", "GeneratedScene", "SCENE_FILE", "generate", "option_names",
           "write_generated"]
