"""Progress on the terminal: the one tqdm bar of long work (the task engine, the Monte
Carlo, the sweeps), shown only when stderr is a terminal."""
from __future__ import annotations

import sys

__all__ = ["progress_bar"]


def progress_bar(progress: bool, total: int, initial: int, unit: str, desc: str):
    """A tqdm bar on stderr, shown only when ``progress`` and stderr is a terminal.

    Parameters
    ----------
    progress : bool
        Whether progress is wanted.
    total, initial : int
        Units of work in all, and already done (resumed).
    unit, desc : str
        What a unit is, and what the work is.

    Returns
    -------
    tqdm.tqdm
    """
    from tqdm import tqdm          # a terminal bar: tqdm.auto warns in a Jupyter kernel
    return tqdm(total=total, initial=initial, unit=unit, desc=desc,
                disable=not (bool(progress) and sys.stderr.isatty()), file=sys.stderr,
                dynamic_ncols=True)
