"""An export's folder written all or nothing: the files of
:func:`biped_casadi.control.export.c_sources` staged beside the destination and renamed
into place (an earlier export there replaced, any other folder refused)."""
from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import tempfile
from pathlib import Path

from ..files import file_path, name_destination
from .export import HEADER, MARKER
from .export_running import RUNNING_HEADER

__all__ = ["check_destination", "staged_export", "Stage", "write_export", "file_digest"]


def _is_export(folder: Path) -> bool:
    """The folder holds an export: a walking or a running controller's header."""
    for name in (HEADER, RUNNING_HEADER):
        try:
            with open(folder / name, encoding="utf-8") as f:
                if f.read(len(MARKER)) == MARKER:
                    return True
        except OSError:
            pass
    return False


def check_destination(out) -> Path:
    """``out`` checked as a folder an export may be written to.

    Absent, empty, or an earlier export (which the new one replaces).

    Parameters
    ----------
    out : str or Path
        The folder.

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        Naming ``out`` when it is a file or a folder holding something else.
    """
    p = file_path(out, "out")
    if p.exists() or p.is_symlink():
        if not p.is_dir():
            raise ValueError(f"out: {p} exists and is not a folder")
        if any(p.iterdir()) and not _is_export(p):
            raise ValueError(f"out: {p} is a folder that holds files other than an export "
                             "(give a new or empty folder)")
    return p


class Stage:
    """The temporary folder of an export being written (:func:`staged_export`).

    Parameters
    ----------
    path : Path
        The folder; its files move to the destination when the block ends.
    """

    def __init__(self, path: Path):
        self.path = path
        self.keep = True

    def discard(self):
        """Leave the destination untouched: the staged files are removed at the end."""
        self.keep = False


@contextlib.contextmanager
def staged_export(files: dict, out, extra: dict | None = None):
    """Stage an export's files beside ``out``; move them into place when the block ends.

    All or nothing.

    The block may work on the staged files (compile, verify, rewrite one); an earlier
    export at ``out`` is replaced in one rename when the block ends normally.  On an
    exception, or after :meth:`Stage.discard`, nothing is left and ``out`` is untouched.

    Parameters
    ----------
    files : dict
        Name (relative, '/'-separated) -> text, e.g. :func:`c_sources`.
    out : str or Path
        The folder (absent, empty or an earlier export: :func:`check_destination`).
    extra : dict, optional
        Name -> bytes, written too (e.g. a copy of the gait file).

    Yields
    ------
    Stage
        With ``path``, the temporary folder.
    """
    out = check_destination(out)
    parent = out.absolute().parent
    parent.mkdir(parents=True, exist_ok=True)
    stage = Stage(Path(tempfile.mkdtemp(prefix=f".{out.name}.export-", dir=parent)))
    tmp, old = stage.path, None
    try:
        for name, text in files.items():
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_text(text, encoding="utf-8")
        for name, data in (extra or {}).items():
            (tmp / name).write_bytes(data)
        yield stage
        if not stage.keep:
            return
        os.chmod(tmp, 0o755)
        if out.exists():
            check_destination(out)
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=parent))
            os.rmdir(old)
            os.replace(out, old)
        os.replace(tmp, out)
    except BaseException as e:
        if old is not None and old.exists() and not out.exists():
            os.replace(old, out)
        name_destination(e, out, tmp)
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


def write_export(files: dict, out, extra: dict | None = None) -> Path:
    """Write an export's files into the folder ``out``, all or nothing.

    :func:`staged_export` with nothing done in between.

    Parameters
    ----------
    files : dict
        Name -> text, e.g. :func:`c_sources`.
    out : str or Path
        The folder (absent, empty or an earlier export).
    extra : dict, optional
        Name -> bytes.

    Returns
    -------
    Path
        ``out``.
    """
    with staged_export(files, out, extra):
        pass
    return Path(out)


def file_digest(path) -> str:
    """SHA-256 of a file's bytes (hex).

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    str
    """
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
