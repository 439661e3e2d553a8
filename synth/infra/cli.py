"""The house style of both command lines (``python -m synth``, ``python -m eval``).

* One argument parser class whose errors are one line ``error: …`` (no usage dump).
* The same argument validators (integers with a lower bound, finite floats with bounds).
* The same exit codes: 0 ok, 1 a check that fails, 2 bad input (one line ``error: …`` on
  stderr), 3 an internal error, 130 interrupted. An unexpected exception (a bug) prints one line
  ``error: internal error: …`` and exits with 3 (not 1, which says that a check failed); set
  ``REFSTEREO_TRACEBACK=1`` to see the traceback.
* The same ``--out`` rule (:mod:`synth.infra.fileio`).
* The same vocabulary, added by the helpers below: a scene is the positional ``scene``;
  ``--out`` says what it writes and the rule; ``-D NAME=VALUE`` overrides a scene default;
  ``--no-progress`` (alias ``--quiet``) silences progress output; ``--json`` prints the report
  as JSON to stdout (the human summary then goes to stderr). ``tests/test_cli_vocabulary.py``
  walks every subcommand of both command lines and checks it.
* ``--version`` prints ``refractive-stereo X.Y.Z`` (:func:`package_version`); no command at all
  prints the help (the list of commands) to stdout and exits 0.
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import re
import sys
import traceback

EXIT_OK, EXIT_CHECK_FAILED, EXIT_BAD_INPUT, EXIT_INTERNAL_ERROR, EXIT_INTERRUPTED = 0, 1, 2, 3, 130


class CLIError(Exception):
    """A user error: printed as one line ``error: <message>`` with exit code 2."""


#: Attribute of a parsed namespace: ``{dest: option string}`` of the options given on the
#: command line (see :func:`given`).
GIVEN = "_given_options"


class _RecordsGiven:
    """Mixed into an option's action class: records that the option was given."""

    def __call__(self, parser, namespace, values, option_string=None):
        given_options = getattr(namespace, GIVEN, None)
        if given_options is None:
            given_options = {}
            setattr(namespace, GIVEN, given_options)
        given_options[self.dest] = option_string or self.option_strings[0]
        return super().__call__(parser, namespace, values, option_string)


_RECORDING_CLASSES: dict = {}


def _record_given_options(parser: argparse.ArgumentParser) -> None:
    """Make every option of ``parser`` (and of its subparsers) record itself when given."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _record_given_options(sub)
        elif action.option_strings and not isinstance(action, (_RecordsGiven,
                                                                argparse._HelpAction)):
            cls = type(action)
            if cls not in _RECORDING_CLASSES:
                _RECORDING_CLASSES[cls] = type(f"Recorded{cls.__name__}", (_RecordsGiven, cls), {})
            action.__class__ = _RECORDING_CLASSES[cls]


#: What argparse takes for a negative number, not an option: ``-100``, ``-.5``, ``-1e9`` and the
#: lists ``-100,2000`` (argparse's own rule knows only ``-100`` and ``-.5``: ``--depth-range
#: -100,2000`` was "expected one argument" instead of what is wrong with the value).
NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?(,[-+]?[\d.eE+-]*)*$")


class Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line ``error: …`` (no usage dump) and exit 2, and
    which records the options given on the command line (:func:`given`). A value that starts
    with a minus and reads as a number or a list of numbers (:data:`NEGATIVE_NUMBER`) is the
    option's value, which its validator then judges."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_NUMBER

    def error(self, message):
        raise CLIError(message)

    def parse_known_args(self, args=None, namespace=None):
        _record_given_options(self)
        return super().parse_known_args(args, namespace)


def given(args, dest: str) -> str | None:
    """The option string (e.g. ``--spp``) with which the option stored in ``args.<dest>`` was
    given on the command line, or None when it was not (its value is then the default)."""
    return getattr(args, GIVEN, {}).get(dest)


def refuse_given(args, dests, why: str) -> None:
    """CLIError ``<option> does not apply <why>`` for the first of the options ``dests``
    (their ``dest`` names) given on the command line: an option that cannot apply is refused,
    never ignored."""
    for dest in dests:
        option = given(args, dest)
        if option:
            raise CLIError(f"{option} does not apply {why}")


def option_number(value: float) -> str:
    """A number as a user types it on the command line: the shorter of its plain and its
    scientific form (12 significant digits), the exponent without ``+`` and leading zeros
    (``1e9``, not ``1e+09``; ``0.5``; ``1000``; ``2.5e-5``), so that a message that suggests an
    option value can be copied back."""
    mantissa, exponent = f"{float(value):.11e}".split("e")
    mantissa = mantissa.rstrip("0").rstrip(".")
    scientific = f"{mantissa}e{int(exponent)}"
    plain = f"{float(value):.12g}"
    if "e" in plain or (len(plain) > 6 and len(scientific) < len(plain)):
        return scientific
    return plain


def int_at_least(minimum: int, description: str):
    """An argparse type: an integer >= ``minimum``; the error says ``description``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < minimum:
            raise argparse.ArgumentTypeError(f"expected a {description} integer, got {text!r}")
        return value

    return parse


positive_int = int_at_least(1, "positive")
non_negative_int = int_at_least(0, "non-negative")


def scene_seed(text: str) -> int:
    """An argparse type: a scene's seed, an integer from 0 to :data:`synth.infra.seeds.MAX_SEED` (the
    renderer's sampler seed is 32-bit: a larger seed cannot be honoured)."""
    from synth.infra.seeds import MAX_SEED, seed_range_text

    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"expected an integer from {seed_range_text()}, "
                                         f"got {text!r}")
    return value


def finite_float(minimum: float = -math.inf, *, strict: bool = False, description: str = "finite"):
    """An argparse type: a finite float >= ``minimum`` (> when ``strict``); NaN and ±inf refused."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        ok = math.isfinite(value) and (value > minimum if strict else value >= minimum)
        if not ok:
            raise argparse.ArgumentTypeError(f"expected a {description} number, got {text!r}")
        return value

    return parse


any_float = finite_float(description="finite")
positive_float = finite_float(0.0, strict=True, description="positive finite")
non_negative_float = finite_float(0.0, description="non-negative finite")


class WaterIndex(float):
    """The float :func:`water_index_argument` returns; ``note`` says how it was computed from
    temperature and salinity (None for a plain number), to be printed once to the user."""

    note: str | None = None

    def __new__(cls, value: float, note: str | None = None):
        self = super().__new__(cls, value)
        self.note = note
        return self


def water_index_argument(text: str) -> float:
    """An argparse type: a water index, as a number (``1.339``) or from the water's temperature
    and salinity, ``T=12,S=35[,wavelength=550]`` (°C, PSU, nm; Quan & Fry 1995,
    :mod:`measure.calibration.water_index`). Returns a :class:`WaterIndex` whose ``note`` says how."""
    from measure.calibration.water_index import WaterIndexError, parse_water_index

    try:
        value, note = parse_water_index(text)
    except WaterIndexError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return WaterIndex(value, note)


#: Help of the options that take a water index.
WATER_INDEX_HELP = ("water index: a number, or T=<°C>,S=<PSU>[,wavelength=<nm>] for Quan & Fry "
                    "1995's index of that water (0–30 °C, 0–35 PSU, 400–700 nm; default 550 nm)")

#: Help of ``--json`` everywhere.
JSON_HELP = "print the report as JSON to stdout (the summary then goes to stderr)"
#: Help of ``-D`` everywhere.
DEFINE_HELP = "override a <default> of the scene (repeatable)"
#: Help of ``--no-progress`` everywhere.
NO_PROGRESS_HELP = "no progress output"
#: Help of the scene positional everywhere.
SCENE_HELP = "Mitsuba scene file (e.g. scenes/paper_plane.xml)"


def add_scene_argument(parser, default: str | None = None) -> None:
    """The positional ``scene`` (optional when ``default`` is given)."""
    if default is None:
        parser.add_argument("scene", help=SCENE_HELP)
    else:
        parser.add_argument("scene", nargs="?", default=default,
                            help=f"{SCENE_HELP}; default {default}")


def out_path(text: str) -> str:
    """An argparse type: an output path, refused when empty or blank (``--out ''`` was "--out
    exists and holds files this command did not write": the empty path is the current
    directory)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"the path is empty ({text!r}): give a directory or "
                                         f"file name")
    return text


def add_out_option(parser, command: str, default: str | None = None, *, what: str = "directory",
                   rule: str | None = None, required: bool | None = None) -> None:
    """``--out``: the output ``what`` (directory or file) of ``command`` and the rule that
    guards it — by default the project's: written whole or not at all, and an existing one is
    replaced only if ``command`` wrote it (:class:`synth.infra.fileio.OutputDir`). ``required``
    (default: when there is no ``default``): False makes it an optional extra output."""
    rule = rule or (f"written whole or not at all; an existing one is replaced only if it is an "
                    f"earlier output of {command}")
    required = default is None if required is None else required
    where = ("required" if required else "optional" if default is None
             else f"default {default}")
    parser.add_argument("--out", default=default, required=required, type=out_path,
                        metavar="FILE" if what == "file" else "DIR",
                        help=f"output {what} ({where}); {rule}")


def add_define_option(parser) -> None:
    """``-D NAME=VALUE`` (repeatable) into ``args.defines``."""
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE",
                        help=DEFINE_HELP)


#: Help of ``--full-film`` (synth render, synth dataset, eval run).
FULL_FILM_HELP = ("render every pixel with --spp samples instead of adaptively (the default: a "
                  "1-spp pilot over the film, then the samples only on the pixels it saw light "
                  "on, with a 3-px margin; docs/speed.md)")


def add_full_film_option(parser) -> None:
    """``--full-film`` into ``args.full_film``."""
    parser.add_argument("--full-film", action="store_true", help=FULL_FILM_HELP)


def add_cluster_options(parser) -> None:
    """``--scheduler``, ``--workers`` and ``--connect-timeout``: where the Dask tasks of
    ``eval sweep`` and ``synth suite`` run (:func:`synth.infra.cluster.connect`)."""
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="submit to a running Dask scheduler (tcp://HOST:PORT) instead of "
                             "starting a local cluster")
    parser.add_argument("--workers", type=positive_int, default=None, metavar="N",
                        help="local cluster: N single-threaded worker processes (default: one "
                             "per core)")
    parser.add_argument("--connect-timeout", type=positive_float, default=5.0, metavar="S",
                        help="seconds to wait for --scheduler to answer (default 5)")


def add_progress_option(parser) -> None:
    """``--no-progress`` (alias ``--quiet``) into ``args.no_progress``."""
    parser.add_argument("--no-progress", "--quiet", dest="no_progress", action="store_true",
                        help=NO_PROGRESS_HELP)


#: ``dest`` names of the board options (:func:`add_board_options`).
BOARD_OPTIONS = ("board", "squares", "inner_corners", "square_mm", "marker_mm", "dictionary",
                 "circles", "pitch_mm", "circle_mm")
#: The options of a chessboard or ChArUco board, and of a circle grid.
SQUARE_OPTIONS = ("squares", "inner_corners", "square_mm", "marker_mm", "dictionary")
CIRCLE_OPTIONS = ("circles", "pitch_mm", "circle_mm")
#: The board ``synth boards`` renders when none is given.
DEFAULT_BOARD = {"board": "chessboard", "squares": "11x8", "square_mm": 40.0}


def add_board_options(parser, defaults: bool = True, needed: str = "",
                      circles: bool = False) -> None:
    """The board of ``synth boards`` and ``eval calibrate``: ``--board chessboard|charuco
    --squares COLSxROWS --square-mm S [--marker-mm M --dictionary NAME]`` (:func:`board_from_args`
    builds the :class:`measure.calibration.board.Board`). With ``defaults`` False nothing has a default
    (``needed`` says when they are required). ``circles``: the circle grids too (``--board
    circles|acircles --circles COLSxROWS --pitch-mm P [--circle-mm D]``)."""
    def default(name):
        return DEFAULT_BOARD[name] if defaults else None

    def said(name, unit=""):
        return f"default {DEFAULT_BOARD[name]}{unit}" if defaults else needed

    kinds = ("chessboard", "charuco") + (("circles", "acircles") if circles else ())
    parser.add_argument("--board", choices=kinds, default=default("board"),
                        help="board kind (default chessboard)" + (
                            "; circles, acircles: OpenCV's symmetric and asymmetric circle "
                            "grids (findCirclesGrid)" if circles else ""))
    parser.add_argument("--squares", default=default("squares"), metavar="COLSxROWS",
                        help=f"squares of the board, COLSxROWS ({said('squares')}); or "
                             f"--inner-corners")
    parser.add_argument("--inner-corners", default=None, metavar="COLSxROWS",
                        help="instead of --squares: the inner corners, as OpenCV's pattern "
                             "size counts them (9x6 is a board of 10x7 squares)")
    parser.add_argument("--square-mm", type=positive_float, default=default("square_mm"),
                        help=f"square side, mm ({said('square_mm', ' mm') if defaults else needed})")
    parser.add_argument("--marker-mm", type=positive_float, default=None,
                        help="ChArUco only: ArUco marker side, mm (default half the square)")
    parser.add_argument("--dictionary", default=None,
                        help="ChArUco only: OpenCV's predefined ArUco dictionary (default "
                             "DICT_5X5_1000)")
    if circles:
        parser.add_argument("--circles", default=None, metavar="COLSxROWS",
                            help="circle grid: dots per row x rows, OpenCV's pattern size "
                                 "(e.g. 4x11 for its asymmetric sample)")
        parser.add_argument("--pitch-mm", type=positive_float, default=None,
                            help="circle grid: OpenCV's spacing s, mm (dots at (j·s, i·s); "
                                 "asymmetric ((2j + i mod 2)·s, i·s))")
        parser.add_argument("--circle-mm", type=positive_float, default=None,
                            help="circle grid: the dots' diameter, mm (optional: given, the "
                                 "centroid of each dot's image is moved to the image of its "
                                 "centre, through the port where there is one)")


def board_from_args(args):
    """The :class:`measure.calibration.board.Board` of :func:`add_board_options`' options; CLIError names
    what does not make a board."""
    from measure.calibration.board import CHARUCO_DICTIONARY, Board, BoardError

    kind = args.board or DEFAULT_BOARD["board"]
    if kind in ("circles", "acircles"):
        return _circle_board(args, kind)
    refuse_given(args, CIRCLE_OPTIONS, f"to a {kind} (circle grids only)")
    inner = getattr(args, "inner_corners", None)
    if inner is not None and given(args, "squares"):
        raise CLIError(f"--squares {args.squares} and --inner-corners {inner}: give one (a board "
                       f"of COLSxROWS squares has (COLS-1)x(ROWS-1) inner corners)")
    option, text = ("--inner-corners", inner) if inner is not None else ("--squares", args.squares)
    example = "10x7" if inner is None else "9x6"
    try:
        cols, rows = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise CLIError(f"{option} must be COLSxROWS (e.g. {example}), got {text!r}") from None
    if inner is not None:
        if cols < 2 or rows < 2:
            raise CLIError(f"--inner-corners {inner}: at least 2x2 inner corners")
        cols, rows = cols + 1, rows + 1
    if kind != "charuco":
        refuse_given(args, ("marker_mm", "dictionary"), "to a chessboard (ChArUco only)")
    ratio = 0.5 if args.marker_mm is None else args.marker_mm / args.square_mm
    if args.marker_mm is not None and args.marker_mm >= args.square_mm:
        raise CLIError(f"--marker-mm {args.marker_mm:g}: the marker must be smaller than the "
                       f"square ({args.square_mm:g} mm)")
    try:
        return Board(kind, (cols, rows), args.square_mm, ratio,
                     args.dictionary or CHARUCO_DICTIONARY)
    except BoardError as exc:
        raise CLIError(str(exc)) from None


def _circle_board(args, kind: str):
    """:func:`board_from_args` of a circle grid."""
    from measure.calibration.board import Board, BoardError

    refuse_given(args, SQUARE_OPTIONS, f"to a circle grid (--board {kind}: give --circles "
                                       f"and --pitch-mm)")
    if args.circles is None or args.pitch_mm is None:
        raise CLIError(f"--board {kind}: give --circles COLSxROWS (dots per row x rows) and "
                       f"--pitch-mm")
    try:
        cols, rows = (int(v) for v in str(args.circles).lower().split("x"))
    except ValueError:
        raise CLIError(f"--circles must be COLSxROWS (e.g. 4x11), got {args.circles!r}") from None
    try:
        return Board(kind, (cols, rows), args.pitch_mm, circle_mm=args.circle_mm or 0.0)
    except BoardError as exc:
        raise CLIError(str(exc)) from None


def add_json_option(parser) -> None:
    """``--json``: print the report as JSON to stdout."""
    parser.add_argument("--json", action="store_true", help=JSON_HELP)


#: The distribution whose version ``--version`` prints.
DISTRIBUTION = "refractive-stereo"


def package_version() -> str:
    """The version of this project: the installed distribution's (``importlib.metadata``), or,
    when it is not installed (a bare checkout on ``PYTHONPATH``), the ``version`` in the
    ``pyproject.toml`` beside the packages; ``"unknown"`` if neither says."""
    import importlib.metadata
    import re
    from pathlib import Path

    try:
        return importlib.metadata.version(DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:
        pass
    try:
        text = (Path(__file__).resolve().parents[2] / "pyproject.toml").read_text("utf-8")
    except OSError:
        return "unknown"
    project = re.search(r"(?ms)^\[project\]\s*$(.*?)(?=^\[|\Z)", text)
    version = project and re.search(r'(?m)^version\s*=\s*"([^"]+)"', project.group(1))
    return version.group(1) if version else "unknown"


def command_parser(prog: str, description: str, modules) -> Parser:
    """The parser of a command line with one subcommand per module of ``modules`` (in ``--help``
    order): each module's ``add_parser(subparsers)`` adds its subparser, whose ``main(args)``
    :func:`run_command` runs. ``--version`` prints :func:`package_version`; the command may be
    left out (:func:`run_command` then prints the help)."""
    parser = Parser(prog=prog, description=description)
    parser.add_argument("--version", action="version",
                        version=f"{DISTRIBUTION} {package_version()}")
    subparsers = parser.add_subparsers(dest="command", metavar="command", required=False,
                                       parser_class=Parser)
    for module in modules:
        before = set(subparsers.choices)
        module.add_parser(subparsers)
        for added in set(subparsers.choices) - before:
            subparsers.choices[added].set_defaults(_main=module.main)
    return parser


def one_line(message) -> str:
    """``message`` as one line (whitespace, including newlines, collapsed)."""
    return " ".join(str(message).split())


def run_command(parser, argv=None) -> int:
    """Parse ``argv`` with ``parser`` (whose subparsers set ``_main``), run it, return the exit
    code. ``parser`` is an ``ArgumentParser`` or a function that builds one (then building it —
    importing the command modules — is covered too). Bad input of any kind — :class:`CLIError`,
    ``ValueError`` and its subclasses (scene, dataset, output errors), ``OSError`` — is one line
    ``error: …`` and exit 2. No command: the help on stdout, exit 0; ``--help`` and
    ``--version`` return 0 too. A SIGINT at any moment (:mod:`synth.infra.interrupt`), even one a
    library swallowed or turned into another error, is the one line ``error: interrupted`` and
    exit 130."""
    from synth.infra import interrupt

    with interrupt.handling():
        try:
            code, error = _run(parser, argv)
        except KeyboardInterrupt:
            code, error = EXIT_INTERRUPTED, "interrupted"
        if interrupt.requested():
            code, error = EXIT_INTERRUPTED, "interrupted"
        if error:
            print(f"error: {error}", file=sys.stderr)
    return code


#: The project's own top-level packages (a missing one of these is a bug, not a missing
#: dependency).
OWN_PACKAGES = ("measure", "synth", "eval", "tests")


def missing_dependency(exc: ModuleNotFoundError) -> str | None:
    """The one line that says a dependency is not installed in this Python (and how to get the
    project's environment), or None when the missing module is one of the project's own."""
    name = exc.name or str(exc)
    if name.split(".")[0] in OWN_PACKAGES:
        return None
    return (f"the Python module {name!r} is not installed in this Python ({sys.executable}): "
            f"run the commands with the project's environment — source .venv/bin/activate "
            f"(created by make setup) or .venv/bin/python -m …")


def _run(parser, argv) -> tuple[int, str | None]:
    """``(exit code, the error line or None)`` of one command (see :func:`run_command`)."""
    try:
        if not isinstance(parser, argparse.ArgumentParser):
            parser = parser()
        try:
            args = parser.parse_args(argv)
        except SystemExit as exc:  # --help, --version: argparse has printed them
            return (exc.code if isinstance(exc.code, int) else EXIT_OK), None
        if getattr(args, "_main", None) is None:  # no command: what there is to do
            parser.print_help(sys.stdout)
            return EXIT_OK, None
        return int(args._main(args) or 0), None
    except (CLIError, ValueError) as exc:
        return EXIT_BAD_INPUT, one_line(exc)
    except OSError as exc:
        where = f" {exc.filename}" if getattr(exc, "filename", None) else ""
        return EXIT_BAD_INPUT, f"{one_line(exc.strerror or exc)}{':' if where else ''}{where}"
    except MemoryError:
        return EXIT_BAD_INPUT, ("out of memory (try a smaller image, fewer samples per pixel or "
                                "fewer targets)")
    except Exception as exc:  # a bug: one line, the traceback on request
        missing = missing_dependency(exc) if isinstance(exc, ModuleNotFoundError) else None
        if missing is not None:  # not a bug: a Python without the project's dependencies
            return EXIT_BAD_INPUT, missing
        if os.environ.get("REFSTEREO_TRACEBACK"):
            traceback.print_exc()
        return EXIT_INTERNAL_ERROR, (f"internal error: {type(exc).__name__}: {one_line(exc)} "
                                   f"(set REFSTEREO_TRACEBACK=1 for the traceback)")


def process_main(main) -> None:
    """Run ``main()`` (a command line's ``main``) as the whole process and exit with its code:
    the entry of ``python -m synth|eval`` and of the console scripts. SIGINT is handled from
    here on (:mod:`synth.infra.interrupt`). Once the command has reported, a Ctrl-C no longer
    interrupts the exit (its code stands). An interrupted command ends at once after its one
    line: ``os._exit(130)`` once the streams are flushed, without the interpreter's shutdown,
    whose finalizers would print more (Dask's ``atexit`` of a cluster cut short, Open3D's leak
    report of an import cut short) — the command has already removed what it had staged."""
    import signal

    from synth.infra import interrupt

    interrupt.install()
    from synth.infra.blas import one_blas_thread

    one_blas_thread()
    try:
        code = main()
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        code = EXIT_INTERRUPTED
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if code == EXIT_INTERRUPTED:
        _flush_streams()
        os._exit(code)
    # The interpreter's last collections would walk every object the command made: 0.3-0.5 s
    # after eval run (Mitsuba, Open3D, matplotlib). Frozen, they go with the process.
    gc.freeze()
    _leave(code)


#: Libraries whose teardown at the interpreter's exit takes long (:func:`_leave`).
SLOW_TEARDOWN = ("drjit", "mitsuba", "open3d", "matplotlib", "dask")


def _leave(code: int) -> None:
    """End the process with ``code`` once the command is done: the ``atexit`` functions run
    (Dask's, multiprocessing's, …) and the streams are flushed, then ``os._exit`` — without the
    interpreter's teardown of every module and the libraries' destructors (Dr.Jit's, Open3D's),
    which took 1.1-1.8 s of wall clock after ``eval run`` on the loaded 2-core machine and
    0.07-0.13 s this way; every output is already written and renamed in place. Only where
    the command loaded one of those libraries (:data:`SLOW_TEARDOWN`): a light command (its
    ``--help``, an argument error) exits as any program does, with ``SystemExit``. Where a
    thread other than the main one still runs (a thread of the command's not joined), the
    ordinary exit waits for it. (In-process, call the command line's ``main(argv)``: it
    returns the code.)"""
    import atexit
    import threading

    if not any(name in sys.modules for name in SLOW_TEARDOWN) or any(
            t.is_alive() and not t.daemon for t in threading.enumerate()
            if t is not threading.main_thread()):
        sys.exit(code)
    atexit._run_exitfuncs()
    _flush_streams()
    os._exit(code)


def _flush_streams() -> None:
    """Standard output and error flushed before ``os._exit`` (a closed stream is let be)."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass


__all__ = ["BOARD_OPTIONS", "DEFAULT_BOARD", "add_board_options", "add_cluster_options", "board_from_args",
           "DEFINE_HELP", "DISTRIBUTION", "EXIT_BAD_INPUT", "EXIT_CHECK_FAILED",
           "EXIT_INTERNAL_ERROR", "EXIT_INTERRUPTED", "EXIT_OK", "JSON_HELP", "NO_PROGRESS_HELP",
           "SCENE_HELP",
           "add_define_option", "add_json_option", "add_out_option", "add_progress_option",
           "add_scene_argument", "any_float", "option_number", "out_path", "CLIError",
           "command_parser", "finite_float",
           "given", "int_at_least", "non_negative_float", "non_negative_int", "one_line",
           "package_version", "Parser", "positive_float", "positive_int", "process_main",
           "refuse_given", "run_command", "scene_seed", "WATER_INDEX_HELP", "WaterIndex",
           "water_index_argument"]
