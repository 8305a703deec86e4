"""Where the results of tasks are kept: one pickle per task key in the cache folder."""
from __future__ import annotations

import contextlib
import pickle
from pathlib import Path

from biped_casadi.caching import cache_dir
from biped_casadi.files import write_bytes_atomic

__all__ = ["ResultStore", "MISSING"]

#: what :meth:`ResultStore.read` returns for a key with no usable result
MISSING = object()


class ResultStore:
    """Results of tasks kept between runs: ``<cache>/tasks/<key[:2]>/<key>.pkl``.

    Each file holds the task's name, its value and the seconds it took.  A file that
    cannot be read is treated as absent (the task runs again and replaces it); a folder
    that cannot be written keeps nothing, without failing the run.

    Parameters
    ----------
    folder : str, Path or False, optional
        The cache folder (default :func:`biped_casadi.cache_dir`); False keeps nothing.
    """

    def __init__(self, folder=None):
        self.enabled = folder is not False
        self.root = cache_dir(None if folder is False else folder) / "tasks"

    def path(self, key: str) -> Path:
        """The file of one key.

        Parameters
        ----------
        key : str
            A task key.

        Returns
        -------
        Path
        """
        return self.root / key[:2] / f"{key}.pkl"

    def empty(self) -> bool:
        """Whether nothing is kept (or nothing can be): every task will be computed.

        Returns
        -------
        bool
        """
        if not self.enabled:
            return True
        try:
            return not any(self.root.iterdir())
        except OSError:
            return True

    def read(self, key: str):
        """The kept record of a key.

        Parameters
        ----------
        key : str
            A task key.

        Returns
        -------
        dict or MISSING
            ``name``, ``value``, ``seconds``.
        """
        p = self.path(key)
        if not self.enabled or not p.is_file():
            return MISSING
        try:
            rec = pickle.loads(p.read_bytes())
        except Exception:            # noqa: BLE001 - a damaged entry is computed again
            return MISSING
        return rec if isinstance(rec, dict) and "value" in rec else MISSING

    def write(self, key: str, name: str, value, seconds: float) -> bool:
        """Keep a result (atomically: the file is complete or absent).

        Parameters
        ----------
        key, name : str
            The task's key and name.
        value : object
            Its result (picklable).
        seconds : float
            How long it took.

        Returns
        -------
        bool
            Whether it was written.
        """
        if not self.enabled:
            return False
        data = pickle.dumps(dict(name=name, value=value, seconds=float(seconds)),
                            protocol=pickle.HIGHEST_PROTOCOL)
        with contextlib.suppress(OSError):
            p = self.path(key)
            p.parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(p, data)
            return True
        return False
