"""An image file read with OpenCV and nothing printed. OpenCV's log (``[ WARN:0…] imread_(…):
can't open/read file``, ``findDecoder``) and the codec libraries' messages, which go straight to
the process's standard error (libjpeg's ``Premature end of JPEG file``, libpng's ``libpng
error: …``), used to precede a command's one ``error:`` line about the same file: the file
descriptor 2 is pointed at the null device for the call (:func:`quiet_stderr`) and the caller
says what is wrong, naming the file."""

from __future__ import annotations

import os
import sys
import threading
from contextlib import contextmanager

_LOCK = threading.Lock()


@contextmanager
def quiet_stderr():
    """The process's standard error (file descriptor 2, where C libraries write) on the null
    device for the block; Python's ``sys.stderr`` is flushed first and restored after."""
    with _LOCK:
        try:
            sys.stderr.flush()
            saved = os.dup(2)
        except (OSError, ValueError, AttributeError):  # no descriptor 2 to move
            yield
            return
        try:
            null = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(null, 2)
            finally:
                os.close(null)
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)


def imread(path, flags):
    """``cv2.imread(path, flags)`` with nothing printed (module docs): the image, or None when
    OpenCV cannot read it."""
    import cv2

    with quiet_stderr():
        return cv2.imread(os.fspath(path), flags)


__all__ = ["imread", "quiet_stderr"]
