"""The standard output of a command, naming itself when a write to it fails.

A write that fails for want of space (``ENOSPC``) raises an ``OSError`` without a file
name: with the output redirected to a file on a full disk, the one-line error would say
"No space left on device" without saying that it was the output (and which file).  While
a command runs, ``sys.stdout`` is wrapped so that such an error names it, and it is
flushed before the command ends so that the error is reported (not lost at exit).
"""
from __future__ import annotations

import contextlib
import os
import stat
import sys

__all__ = ["named_stdout"]


def _name(stream) -> str:
    """'stdout', with the file it is redirected to when that is a regular file."""
    try:
        fd = stream.fileno()
        if stat.S_ISREG(os.fstat(fd).st_mode):
            return f"stdout ({os.readlink(f'/proc/self/fd/{fd}')})"
    except (OSError, ValueError, AttributeError):
        pass
    return "stdout"


class _Named:
    """A text stream whose failed writes and flushes name it (everything else passes
    through)."""

    def __init__(self, stream):
        self._stream = stream

    def _name(self, e: OSError):
        if e.filename is None and not isinstance(e, BrokenPipeError):
            e.filename = _name(self._stream)

    def write(self, text):
        try:
            return self._stream.write(text)
        except OSError as e:
            self._name(e)
            raise

    def flush(self):
        try:
            return self._stream.flush()
        except OSError as e:
            self._name(e)
            raise

    def __getattr__(self, name):
        return getattr(self._stream, name)


@contextlib.contextmanager
def named_stdout():
    """While the block runs, ``sys.stdout``'s failed writes name it; flushed at the end.

    Yields
    ------
    None
    """
    real = sys.stdout
    sys.stdout = _Named(real)
    try:
        yield
        sys.stdout.flush()
    finally:
        sys.stdout = real
