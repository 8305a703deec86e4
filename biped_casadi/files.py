"""Files a user names: reading an input file with one clear reason when it cannot be
read, and writing result files safely: through a temporary file in the same folder,
moved into place only when complete, and removed on any failure (an exception, Ctrl-C),
so a reader never sees half a file and a failed write never damages an earlier result
or leaves a stray temporary file behind; and a lock file that keeps processes sharing a
folder from building the same file at once."""
from __future__ import annotations

import contextlib
import itertools
import os
import time
from pathlib import Path

__all__ = ["atomic_path", "write_text_atomic", "write_bytes_atomic", "read_text_file",
           "name_destination", "file_path", "file_lock"]


def file_path(path, name: str = "path") -> Path:
    """``path`` as a Path, or a TypeError naming ``name`` when it is not a file name.

    Parameters
    ----------
    path : str or os.PathLike
        What the user passed.
    name : str
        The argument's name, used in the error message.

    Returns
    -------
    pathlib.Path
    """
    if isinstance(path, bytes) or not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"{name} must be a file name (str or pathlib.Path), got "
                        f"{type(path).__name__}")
    return Path(path)


def read_text_file(path, what: str, max_bytes: int = 20_000_000) -> str:
    """The UTF-8 text of an input file the user named.

    Parameters
    ----------
    path : str or Path
    what : str
        What the file is, for the message ("robot description file", ...).
    max_bytes : int
        Larger files are refused (they are not what the caller reads).

    Returns
    -------
    str
        The text, without the byte order mark some editors write first (Excel's "CSV
        UTF-8", Notepad): a file with one reads as the same file without; UTF-16 with
        its byte order mark (Excel's "Unicode text") is read too.

    Raises
    ------
    ValueError
        One line naming ``what``, the path and the reason: not found, a broken link, a
        folder, not a regular file (a device, a pipe), too large, unreadable (with the
        system's reason, e.g. permission denied), or not UTF-8 (nor UTF-16) text.
    """
    path = Path(path)
    try:
        if not path.exists():
            raise ValueError(f"{what} {path} is a broken link" if path.is_symlink()
                             else f"{what} not found: {path}")
        if path.is_dir():
            raise ValueError(f"{what} {path} is a folder, not a file")
        if not path.is_file():
            raise ValueError(f"{what} {path} is not a regular file")
        size = path.stat().st_size
        if size > max_bytes:
            raise ValueError(f"{what} {path} is too large ({size} bytes)")
        data = path.read_bytes()
    except OSError as e:
        raise ValueError(f"{what} {path} cannot be read: {e.strerror or e}") from None
    try:
        if data.startswith((b"\xff\xfe", b"\xfe\xff")):     # UTF-16 with its byte order mark
            return data.decode("utf-16")
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"{what} {path} is not a text file (not UTF-8: binary, or text in "
                         f"another encoding to save as UTF-8)") from None


@contextlib.contextmanager
def atomic_path(path):
    """Context manager yielding a temporary path beside ``path``; on a normal exit the
    temporary file replaces ``path`` (``os.replace``, atomic on POSIX), on any exception
    it is removed and ``path`` is left as it was.

    Parameters
    ----------
    path : str or Path
        The file to write; ``path`` must not be a folder.  Missing folders above it are
        created (and removed again if the write fails).

    Yields
    ------
    Path
        Where to write (same folder and suffix as ``path``, so writers that choose a
        format by suffix still work).

    Raises
    ------
    IsADirectoryError
        ``path`` is an existing folder (checked before anything is written).
    OSError
        A failed write (a full disk, ...) names ``path`` as its ``filename``, not the
        temporary file (:func:`name_destination`).
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(21, "Is a directory", str(path))
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    created = []
    try:
        _make_folders(path.parent, created)
        yield tmp
        os.replace(tmp, path)
    except BaseException as e:
        with contextlib.suppress(OSError):
            tmp.unlink()
        for folder in reversed(created):          # the deepest first; left if not empty
            with contextlib.suppress(OSError):
                folder.rmdir()
        name_destination(e, path, tmp)
        raise


def _make_folders(folder: Path, created: list) -> None:
    """Create ``folder`` and its missing parents, appending each to ``created``
    (outermost first)."""
    missing = list(itertools.takewhile(lambda p: not p.is_dir(), (folder, *folder.parents)))
    for p in reversed(missing):
        try:
            p.mkdir()
        except FileExistsError:
            if not p.is_dir():                  # a file there
                raise
            continue                            # made meanwhile by another writer
        created.append(p)


def name_destination(error: BaseException, path, staging=None) -> None:
    """Let a failed write's ``OSError`` name what was being written.

    A write that fails (``ENOSPC``: no space left on device) raises an ``OSError``
    without a file name, so its message would not say which output failed; one naming
    the temporary file or folder the output was staged in names the output instead.

    Parameters
    ----------
    error : BaseException
        The error (anything but an ``OSError`` is left alone).
    path : str or Path
        The output being written.
    staging : str or Path, optional
        Where it was being staged (a temporary file or folder beside it).
    """
    if not isinstance(error, OSError) or isinstance(error, BrokenPipeError):
        return
    name = error.filename
    staged = staging is not None and name is not None and (
        Path(name) == Path(staging) or Path(staging) in Path(name).parents)
    if name is None or staged:
        error.filename = str(path)


def write_bytes_atomic(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through :func:`atomic_path`; returns ``path``."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    return Path(path)


def write_text_atomic(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` through :func:`atomic_path`; returns ``path``."""
    return write_bytes_atomic(path, text.encode("utf-8"))


# ------------------------------------------------------------------ file lock
def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextlib.contextmanager
def file_lock(path: Path, poll: float = 0.2):
    """Hold a lock file beside ``path`` among processes sharing a folder.

    While another live process holds it, wait: two processes then never build the same
    file (a compiled library) at once.  A lock left by a process that died is taken
    over; where the folder cannot be written (or the lock's process id cannot: a full
    disk), the block runs unguarded and no lock file is left.

    Parameters
    ----------
    path : Path
        The file to build.
    poll : float
        Seconds between looks at another process's lock.
    """
    lock = Path(str(path) + ".lock")
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
    except OSError:
        yield
        return
    while True:
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            try:
                pid = int(lock.read_text() or 0)
            except (OSError, ValueError):
                pid = 0
            if pid and pid != os.getpid() and _alive(pid):
                time.sleep(poll)
                continue
            with contextlib.suppress(OSError):
                lock.unlink()                       # its holder died: take it over
            continue
        except OSError:
            yield
            return
        try:
            with os.fdopen(fd, "w") as f:
                f.write(str(os.getpid()))
        except OSError:                             # a full disk: no lock, no stray file
            with contextlib.suppress(OSError):
                lock.unlink()
            yield
            return
        break
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            lock.unlink()
