#!/usr/bin/env bash
# Set up everything `make test` and `make run` need on a Debian/Ubuntu machine:
#   1. system libraries: libusb-1.0 (Open3D imports it) and an LLVM >= 16 shared library
#      (Mitsuba's llvm_* variants; LLVM 15 aborts the process, LLVM 14 is too old),
#   2. a virtual environment .venv with the project and its test extras.
# System packages are installed with apt-get when we are root (or have password-less sudo);
# otherwise the script prints the exact command to run and carries on (Mitsuba then falls back to
# its scalar_rgb variant, about 8x slower).
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
VENV=${VENV:-.venv}

have_libusb() { ldconfig -p 2>/dev/null | grep -q 'libusb-1\.0\.so\.0'; }
find_llvm() {  # newest libLLVM >= 16 on the system, or nothing
  for dir in /usr/lib/x86_64-linux-gnu /usr/lib/aarch64-linux-gnu /usr/lib /usr/lib64 /usr/local/lib; do
    ls "$dir"/libLLVM-[0-9]*.so "$dir"/libLLVM.so.[0-9]* 2>/dev/null || true
  done | grep -E 'libLLVM(-|\.so\.)(1[6-9]|[2-9][0-9])' | sort -V | tail -n 1
}

missing=()
have_libusb || missing+=(libusb-1.0-0)
[ -n "$(find_llvm)" ] || missing+=(LLVM)

if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then SUDO="sudo -n"; else SUDO="none"; fi
  fi
  packages=()
  for m in "${missing[@]}"; do
    if [ "$m" = LLVM ]; then
      # Prefer Debian's libllvm19 (measured to work with Dr.Jit); else the newest libllvmNN >= 16.
      if command -v apt-cache >/dev/null 2>&1 && [ "$SUDO" != none ]; then
        [ -n "$(apt-cache policy libllvm19 2>/dev/null | grep 'Candidate: [0-9]')" ] || $SUDO apt-get update -qq || true
      fi
      llvm_pkg=libllvm19
      if command -v apt-cache >/dev/null 2>&1 && ! apt-cache policy libllvm19 2>/dev/null | grep -q 'Candidate: [0-9]'; then
        llvm_pkg=$(apt-cache pkgnames libllvm 2>/dev/null | grep -E '^libllvm(1[6-9]|[2-9][0-9])$' | sort -V | tail -n 1)
        llvm_pkg=${llvm_pkg:-libllvm19}
      fi
      packages+=("$llvm_pkg")
    else
      packages+=("$m")
    fi
  done
  if [ "$SUDO" = none ] || ! command -v apt-get >/dev/null 2>&1; then
    echo "setup: missing system libraries; please run:  sudo apt-get install -y ${packages[*]}" >&2
  else
    echo "setup: installing system libraries: ${packages[*]}"
    $SUDO apt-get update -qq || true
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${packages[@]}" >/dev/null
  fi
fi

if [ ! -x "$VENV/bin/python" ]; then
  echo "setup: creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
stamp="$VENV/.installed"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "setup: installing the project and its test extras into $VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q -e '.[test]'
  touch "$stamp"
fi

# The project's own modules compiled to bytecode once (an editable install leaves them as
# source): every later process reads the .pyc files, also where PYTHONDONTWRITEBYTECODE is set
# (then nothing is cached otherwise, and each `python -m eval` compiled its ~120 modules again:
# about 0.3-0.5 s of CPU a process; stale files are recompiled here, and Python itself ignores a
# .pyc whose source changed).
"$VENV/bin/python" -m compileall -q -j 0 synth measure eval >/dev/null
