"""The toolkit's one caching mechanism, and where it keeps files.

Building CasADi Functions (a model, a Poincaré map, a compiled closed loop) takes from
milliseconds to seconds; evaluating them is cheap.  Builders are therefore memoised
with :func:`cached`: a bounded least-recently-used table per builder, keyed by what the
result depends on.  An argument contributes its ``cache_key`` attribute when it has one
(a model is keyed by its parameters, a gait by the digest of what defines it, a map by
its gait and options), otherwise the argument itself (numbers, strings, tuples, frozen
dataclasses).  Two content-equal objects therefore share one entry, and an entry never
outlives the bound.

Files: :func:`cache_dir` is the folder for results kept between sessions (optimised
gaits, the stored 9^4 sweep).
"""
from __future__ import annotations

import functools
import os
import threading
from collections import OrderedDict
from pathlib import Path

__all__ = ["cached", "cache_key", "cache_dir"]


def cache_key(obj):
    """The part of a cache key that ``obj`` contributes.

    Parameters
    ----------
    obj : object
        An argument of a memoised builder.

    Returns
    -------
    hashable
        ``obj.cache_key`` when defined, tuples and dicts converted element-wise,
        otherwise ``obj`` itself (which must then be hashable).
    """
    key = getattr(obj, "cache_key", None)
    if key is not None and not callable(key):
        return (type(obj).__name__, key)
    if isinstance(obj, (list, tuple)):
        return tuple(cache_key(o) for o in obj)
    if isinstance(obj, dict):
        return tuple(sorted((k, cache_key(v)) for k, v in obj.items()))
    return obj


def cached(maxsize: int = 16):
    """Decorator: memoise a builder in a bounded LRU table keyed by :func:`cache_key`.

    Works on functions and methods (``self`` contributes its own ``cache_key``).  The
    wrapped function gains ``cache_clear()`` and ``cache_len()``.  Thread-safe: two
    threads asking for the same missing entry may both build it; one result is kept.

    Parameters
    ----------
    maxsize : int
        Entries kept; the least recently used is dropped first.

    Returns
    -------
    callable
        The decorator.
    """
    if not isinstance(maxsize, int) or maxsize < 1:
        raise ValueError(f"maxsize must be a positive integer, got {maxsize!r}")

    def decorate(fn):
        table: OrderedDict = OrderedDict()
        lock = threading.Lock()

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            key = (cache_key(args), cache_key(kwargs))
            with lock:
                if key in table:
                    table.move_to_end(key)
                    return table[key]
            value = fn(*args, **kwargs)
            with lock:
                table[key] = value
                table.move_to_end(key)
                while len(table) > maxsize:
                    table.popitem(last=False)
            return value

        def cache_clear():
            with lock:
                table.clear()

        wrapper.cache_clear = cache_clear
        wrapper.cache_len = lambda: len(table)
        return wrapper

    return decorate


def cache_dir(path=None) -> Path:
    """Folder for results kept between sessions.

    Parameters
    ----------
    path : str or Path, optional
        Use this folder.

    Returns
    -------
    Path
        ``path``, else ``$BIPED_CACHE_DIR``, else ``~/.cache/biped-casadi``.
    """
    if path is not None:
        return Path(path)
    env = os.environ.get("BIPED_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "biped-casadi"
