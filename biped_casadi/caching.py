"""The toolkit's one caching mechanism, and where it keeps files.

Building CasADi Functions (a model, a Poincaré map, a compiled closed loop) takes from
milliseconds to seconds; evaluating them is cheap.  Builders are therefore memoised
with :func:`cached`: a bounded least-recently-used table per builder, keyed by what the
result depends on.  An argument contributes its ``cache_key`` attribute when it has one
(a model is keyed by its parameters, a gait by the digest of what defines it, a map by
its gait and options), otherwise the argument itself (numbers, strings, tuples, frozen
dataclasses).  Two content-equal objects therefore share one entry, and an entry never
outlives the bound.

Files: :func:`cache_dir` is the folder for results kept between sessions; every kind of
result kept there (optimised gaits, the stored 9^4 sweeps, robust designs) is one
:class:`DiskCache`, whose entries are named by the :func:`digest` of what they depend
on and of the kind's version.
"""
from __future__ import annotations

import ast
import contextlib
import dataclasses
import functools
import hashlib
import importlib
import json
import os
import threading
import time
from collections import OrderedDict
from pathlib import Path

__all__ = ["cached", "cache_key", "cache_dir", "digest", "modules_digest", "code_of", "DiskCache",
           "file_lock", "task", "TaskInfo"]


@dataclasses.dataclass(frozen=True)
class TaskInfo:
    """What identifies a task.

    Parameters
    ----------
    name : str
        Module and function.
    version : int
        Its own version (bump it when its result for the same arguments changes without
        any change of code).
    code : str
        The kind of code it runs ('numerical' or 'figures':
        :func:`analysis.tasks.code_version`).
    """

    name: str
    version: int = 1
    code: str = "numerical"


def task(fn=None, *, version: int = 1, code: str = "numerical", name: str | None = None):
    """Mark a pure function as a task, whose results are kept by key.

    :class:`analysis.tasks.Engine` keeps its results on disk by the key of its arguments
    and of the code that computes them.
    The function is returned unchanged (calling it runs it); it gains ``task_info``.  A
    task is a module-level function of typed arguments (numbers, arrays, dataclasses,
    models, gaits, designs) that always returns the same result for the same arguments.

    Parameters
    ----------
    fn : callable
        The function.
    version : int
        The task's own version.
    code : str
        'numerical' or 'figures'.
    name : str, optional
        Default ``module.qualname``.

    Returns
    -------
    callable
    """
    def mark(f):
        f.task_info = TaskInfo(name or f"{f.__module__}.{f.__qualname__}", version, code)
        return f
    return mark(fn) if fn is not None else mark


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


def digest(obj) -> str:
    """SHA-256 (hex) of an object's canonical JSON (sorted keys; str() for other types).

    The one content digest of the toolkit: gait files' checksums, cache entries, sweep
    settings.

    Parameters
    ----------
    obj : object
        Anything JSON can hold (numbers, strings, lists, dicts).

    Returns
    -------
    str
        64 hex digits.
    """
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


_SOURCES: dict = {}


#: the fields of a node that hold statements (where definitions, hence docstrings, are)
_STATEMENT_FIELDS = ("body", "orelse", "finalbody", "handlers", "cases")


def _strip_docstrings(tree):
    """The syntax tree without its docstrings (module, class and function).

    Only statements are visited (a definition is a statement; expressions hold none but
    lambdas, which have no docstring)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(
                    getattr(body[0], "value", None), ast.Constant) \
                    and isinstance(body[0].value.value, str):
                node.body = body[1:] or [ast.Pass()]
        for name in _STATEMENT_FIELDS:
            children = getattr(node, name, None)
            if isinstance(children, list):
                stack.extend(c for c in children if isinstance(c, ast.AST))
    return tree


def code_of(path) -> str:
    """What of a Python file decides what it computes (its syntax tree, ``ast.dump``).

    Docstrings, comments and layout are left out.

    Parameters
    ----------
    path : str or Path
        A Python source file.

    Returns
    -------
    str
    """
    p = Path(path)
    data = p.read_bytes()
    key = (str(p), hashlib.sha256(data).digest())
    if key not in _CODE_OF:      # several code sets share files: each is parsed once
        _CODE_OF[key] = ast.dump(_strip_docstrings(ast.parse(data, filename=str(p))),
                                 include_attributes=False)
    return _CODE_OF[key]


#: code_of's results in this process, by file and content
_CODE_OF: dict = {}


def modules_digest(modules, salt: str = "") -> str:
    """SHA-256 of the code of some modules: the code that decides a kind of result.

    The code of a module is :func:`code_of` (docstrings, comments and layout left out).
    Stored results carry it, so a result of other code is refused or recomputed, and a
    worker running other code is detected; an edit of a docstring keeps them.  Computed
    once per process per argument.

    Parameters
    ----------
    modules : tuple of str
        Module names (imported to find their files).
    salt : str
        Mixed in first (e.g. a results version).

    Returns
    -------
    str
        64 hex digits.
    """
    key = (tuple(modules), salt)
    if key not in _SOURCES:
        h = hashlib.sha256(salt.encode())
        for name in key[0]:
            h.update(name.encode())
            h.update(code_of(importlib.import_module(name).__file__).encode())
        _SOURCES[key] = h.hexdigest()
    return _SOURCES[key]


class DiskCache:
    """One kind of result kept between sessions in :func:`cache_dir`.

    An entry is the file (or folder) ``<cache_dir>/<kind>/<kind>-<key>[suffix]``, ``key``
    the first 20 hex digits of the :func:`digest` of what the result depends on and of
    ``version`` (bump it when the code's result for the same inputs changes).  Writing
    is the caller's (atomically); an entry that cannot be used is recomputed, never
    trusted.

    Parameters
    ----------
    kind : str
        The kind of result (a folder name: 'gaits', 'robust', 'sweeps', ...).
    version : int
        The version of the results of this kind.
    """

    def __init__(self, kind: str, version: int):
        self.kind, self.version = kind, int(version)

    def key(self, body) -> str:
        """The entry's key for what a result depends on.

        Parameters
        ----------
        body : object
            JSON-able description of the inputs.

        Returns
        -------
        str
            20 hex digits.
        """
        return digest(dict(kind=self.kind, version=self.version, body=body))[:20]

    def path(self, body, folder=None, suffix: str = ".json") -> Path:
        """The entry of a result.

        Parameters
        ----------
        body : object
            JSON-able description of the inputs.
        folder : str or Path, optional
            The cache folder (default :func:`cache_dir`).
        suffix : str
            '.json' for a file; '' for a folder.

        Returns
        -------
        Path
        """
        return cache_dir(folder) / self.kind / f"{self.kind}-{self.key(body)}{suffix}"


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
    over; where the folder cannot be written, the block runs unguarded.

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
        with os.fdopen(fd, "w") as f:
            f.write(str(os.getpid()))
        break
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            lock.unlink()
