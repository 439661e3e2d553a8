"""Atomic output: a result directory appears whole or not at all."""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager


def replace_dir(tmp: str, out_dir: str) -> None:
    """Put directory ``tmp`` at ``out_dir``; an existing ``out_dir`` is moved aside, then deleted."""
    if os.path.exists(out_dir):
        if not os.listdir(out_dir):
            os.rmdir(out_dir)
            os.rename(tmp, out_dir)
            return
        trash = tempfile.mkdtemp(prefix=f".{os.path.basename(out_dir)}.old-",
                                 dir=os.path.dirname(out_dir))
        os.rename(out_dir, os.path.join(trash, "old"))
        os.rename(tmp, out_dir)
        shutil.rmtree(trash, ignore_errors=True)
    else:
        os.rename(tmp, out_dir)


@contextmanager
def staged_dir(out_dir):
    """Yield a temporary directory beside ``out_dir``; on success it replaces ``out_dir``.

    On an exception the temporary directory is removed and ``out_dir`` is left as it was.
    """
    out_dir = os.path.abspath(os.fspath(out_dir))
    parent = os.path.dirname(out_dir)
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(out_dir)}.tmp-", dir=parent)
    os.chmod(tmp, 0o755)
    try:
        yield tmp
        replace_dir(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
