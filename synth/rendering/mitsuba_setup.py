"""Pick a Mitsuba 3 variant and import Mitsuba safely.

Order of preference (measured facts in docs/architecture.md, "Facts about the tools"):

1. ``cuda_ad_rgb`` when an NVIDIA GPU is usable (``nvidia-smi -L`` lists one, or ``/dev/nvidia0``
   exists together with ``libcuda.so``);
2. ``llvm_ad_rgb`` when a libLLVM shared library of version >= 16 is found. Its path goes into
   ``DRJIT_LIBLLVM_PATH`` *before* Dr.Jit is imported. LLVM 15 is never chosen: Dr.Jit aborts the
   whole process during code generation with it (nothing to catch); LLVM 14 is refused by
   Dr.Jit as too old. Versions are read from file names only -- nothing is loaded to find out;
3. ``scalar_rgb`` otherwise (always works, about 8x slower).

``DRJIT_LIBLLVM_PATH`` set by the user is respected when its file name says version >= 16.
Call :func:`import_mitsuba` instead of ``import mitsuba`` everywhere in ``synth``.
"""

from __future__ import annotations

import glob
import os
import re
import shutil
import subprocess
import sys

#: Variants this project renders with, in order of preference.
PREFERRED_VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
#: Oldest LLVM that Dr.Jit 1.x generates code with on these machines without aborting.
MIN_LLVM_MAJOR = 16

_LLVM_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib", "/usr/lib64",
              "/usr/local/lib", "/opt/homebrew/opt/llvm/lib", "/usr/local/opt/llvm/lib")
_selected: str | None = None


class VariantError(ValueError):
    """A Mitsuba variant that cannot be used here (unknown, or llvm_* without LLVM >= 16)."""


def llvm_major_from_name(path: str) -> int | None:
    """The LLVM major version in a library's file name (``libLLVM-19.so`` -> 19), else None."""
    name = os.path.basename(path)
    match = re.search(r"libLLVM[-.](?:so\.)?(\d+)", name)
    return int(match.group(1)) if match else None


def find_libllvm(min_major: int = MIN_LLVM_MAJOR) -> str | None:
    """Path of the newest libLLVM with major version >= ``min_major`` on this machine, or None.

    A ``DRJIT_LIBLLVM_PATH`` already in the environment wins when it names such a version.
    """
    preset = os.environ.get("DRJIT_LIBLLVM_PATH")
    if preset and os.path.exists(preset) and (llvm_major_from_name(preset) or 0) >= min_major:
        return preset
    found = []
    for directory in _LLVM_DIRS:
        for path in glob.glob(os.path.join(directory, "libLLVM*")):
            major = llvm_major_from_name(path)
            if major is not None and major >= min_major and os.path.isfile(path):
                found.append((major, len(os.path.basename(path)), path))
    if not found:
        return None
    found.sort(key=lambda item: (-item[0], item[1]))  # newest, then the shortest name
    return found[0][2]


def cuda_usable() -> bool:
    """Whether an NVIDIA GPU looks usable (driver tool lists a GPU, or device + libcuda exist)."""
    smi = shutil.which("nvidia-smi")
    if smi:
        try:
            out = subprocess.run([smi, "-L"], capture_output=True, text=True, timeout=10)
            if out.returncode == 0 and "GPU" in out.stdout:
                return True
        except (OSError, subprocess.SubprocessError):
            pass
    has_lib = any(glob.glob(os.path.join(d, "libcuda.so*")) for d in _LLVM_DIRS)
    return os.path.exists("/dev/nvidia0") and has_lib


def choose_variant(requested: str | None = None) -> str:
    """The variant to use: ``requested`` if given, else the best of :data:`PREFERRED_VARIANTS`.

    Sets ``DRJIT_LIBLLVM_PATH`` when an ``llvm_*`` variant is chosen (before Mitsuba is
    imported). Raises :class:`VariantError` when an ``llvm_*`` variant is requested but no LLVM >= 16
    is found (rather than letting Dr.Jit abort the process); ``VariantError`` is a ``ValueError``.
    """
    if requested:
        if requested.startswith("llvm_"):
            _point_drjit_at_llvm(required=True)
        return requested
    if cuda_usable():
        return "cuda_ad_rgb"
    if _point_drjit_at_llvm(required=False):
        return "llvm_ad_rgb"
    return "scalar_rgb"


def _point_drjit_at_llvm(required: bool) -> bool:
    path = find_libllvm()
    if path is None:
        preset = os.environ.get("DRJIT_LIBLLVM_PATH")
        if preset and "drjit" not in sys.modules:
            os.environ.pop("DRJIT_LIBLLVM_PATH")  # an LLVM < 16 there would abort the process
        if required:
            raise VariantError(f"no libLLVM >= {MIN_LLVM_MAJOR} found for the llvm_* variants "
                               f"(LLVM 15 aborts Dr.Jit); install libllvm19 or use scalar_rgb")
        return False
    if "drjit" not in sys.modules:
        os.environ["DRJIT_LIBLLVM_PATH"] = path
    return True


def import_mitsuba(variant: str | None = None):
    """Import Mitsuba with a variant set; returns ``(mitsuba_module, variant_name)``.

    ``variant`` None picks automatically (:func:`choose_variant`); the first choice in a process
    sticks unless another variant is requested explicitly.
    """
    global _selected
    if variant is None and _selected is not None:
        chosen = _selected
    else:
        chosen = choose_variant(variant)
    import mitsuba as mi

    if chosen not in mi.variants():
        raise VariantError(f"Mitsuba variant {chosen!r} is not available; "
                           f"choose one of {', '.join(mi.variants())}")
    if mi.variant() != chosen:
        try:
            mi.set_variant(chosen)
        except (ImportError, RuntimeError) as exc:  # e.g. cuda_* without a usable GPU
            reason = " ".join(str(exc).split())
            raise VariantError(f"Mitsuba variant {chosen!r} cannot start here: {reason}") from None
    _selected = chosen
    log_to_stderr(mi)
    return mi, chosen


_LOG_ON_STDERR = False


def log_to_stderr(mi) -> None:
    """Send Mitsuba's log (its warnings, e.g. ``[MultijitterSampler] Sample count rounded up to
    6``) to stderr instead of its default stdout: stdout holds a command's report (``--json``
    prints JSON there, which a log line made invalid). Once per process."""
    global _LOG_ON_STDERR
    if _LOG_ON_STDERR:
        return
    logger = mi.logger() if hasattr(mi, "logger") else mi.Thread.thread().logger()

    class _Stderr(mi.Appender):
        def append(self, level, text):
            print(text, file=sys.stderr, flush=True)

        def log_progress(self, progress, name, formatted, eta, ptr=None):
            pass

    logger.clear_appenders()
    logger.add_appender(_Stderr())
    _LOG_ON_STDERR = True


def render(mi, scene, **options):
    """``mi.render(scene, **options)`` without Mitsuba's own word on Ctrl-C. Every render call
    installs Mitsuba's SIGINT handler, which logs ``WARN [integrator_v.cpp:38] Received
    interrupt signal, winding down..`` to stdout before passing the signal on; the command lines
    report an interrupt themselves (one line ``error: interrupted`` on stderr,
    :mod:`synth.infra.interrupt`), so during the call Mitsuba logs errors only. (Loading a scene, where
    Mitsuba's warnings say something about the scene, keeps its level.)"""
    logger = mi.logger() if hasattr(mi, "logger") else mi.Thread.thread().logger()
    level = logger.log_level()
    logger.set_log_level(mi.LogLevel.Error)
    try:
        return mi.render(scene, **options)
    finally:
        logger.set_log_level(level)

