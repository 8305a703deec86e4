"""The toolkit's one cache, its one key scheme and its one code digest.

Keys.  A result is named by the key of what it depends on (:func:`task_key`): the name
and version of the function that computes it, the version of the code behind it
(:func:`code_version`) and the content of its arguments (:func:`argument_key`): numbers
exactly, arrays by their bytes, dataclasses field by field, models and gaits by their
``cache_key``.  The keys of a whole graph are known before anything runs (an argument
that is another task's result contributes that task's key).

Code.  :func:`code_version` is the digest of the *syntax trees* of a set of modules
(:data:`CODE_SETS`) with their docstrings removed, and of the CasADi and NumPy
versions: editing a docstring, a comment or the layout of a line keeps every result;
changing a number or a statement gives new keys (the old results stay on disk, unused).
Results kept in folders of their own (a sweep, a Monte Carlo) carry it; a Dask worker
whose code differs, or a worker or command whose files' code changed after it imported
them (:func:`code_edited`), is refused its tasks (:mod:`analysis.tasks`).

Kept results.  :class:`ResultStore` keeps one file per key in :func:`cache_dir`
(``$BIPED_CACHE_DIR`` or ``~/.cache/biped-casadi``), written atomically and fsynced; a
damaged entry is computed again, never trusted.  :func:`task` marks a function whose
results the task engine (:mod:`analysis.tasks`) keeps there.

In memory.  Building CasADi Functions (a model, a Poincaré map, a compiled closed loop)
takes from milliseconds to seconds; evaluating them is cheap.  Builders are therefore
memoised with :func:`cached`, a bounded least-recently-used table per builder in this
process, keyed by what the built object depends on (:func:`cache_key`).
"""
from __future__ import annotations

import ast
import contextlib
import dataclasses
import functools
import hashlib
import importlib.util
import json
import math
import os
import pickle
import sys
import threading
from collections import OrderedDict
from pathlib import Path

import numpy as np

from .files import file_lock, file_path, write_bytes_atomic

__all__ = ["cached", "cache_key", "cache_dir", "digest", "code_of", "CODE_SETS",
           "code_version", "code_files", "code_edited", "files_differing", "argument_key",
           "task_key", "NotKeyable", "ResultStore", "MISSING", "file_lock", "task", "TaskInfo"]


# ------------------------------------------------------------------------ tasks
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
        The set of code it runs (a key of :data:`CODE_SETS`).
    """

    name: str
    version: int = 1
    code: str = "numerical"


def task(fn=None, *, version: int = 1, code: str = "numerical", name: str | None = None):
    """Mark a pure function as a task, whose results are kept by key.

    The function is returned unchanged (calling it runs it); it gains ``task_info``.  A
    task is a module-level function of typed arguments (numbers, arrays, dataclasses,
    models, gaits, designs) that always returns the same result for the same arguments;
    :class:`analysis.tasks.Engine` runs it and keeps its results under :func:`task_key`.

    Parameters
    ----------
    fn : callable
        The function.
    version : int
        The task's own version.
    code : str
        Its code set (:data:`CODE_SETS`): 'numerical' or 'figures'.
    name : str, optional
        Default ``module.qualname``.

    Returns
    -------
    callable
    """
    if code not in CODE_SETS:
        raise ValueError(f"code must be one of {sorted(CODE_SETS)}, got {code!r}")

    def mark(f):
        f.task_info = TaskInfo(name or f"{f.__module__}.{f.__qualname__}", version, code)
        return f
    return mark(fn) if fn is not None else mark


# -------------------------------------------------------------- memo in memory
def cache_key(obj):
    """The part of a memo's key that ``obj`` contributes (:func:`cached`).

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


# ------------------------------------------------------------------------ keys
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
        return file_path(path)
    env = os.environ.get("BIPED_CACHE_DIR")
    return Path(env) if env else Path.home() / ".cache" / "biped-casadi"


def digest(obj) -> str:
    """SHA-256 (hex) of an object's canonical JSON (sorted keys; str() for other types).

    The content digest of files and settings (gait files' checksums, sweep settings).

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


class NotKeyable(TypeError):
    """An argument of a task whose content cannot be keyed (not a typed value)."""


def _number(x):
    x = float(x)
    return repr(x) if math.isfinite(x) else str(x)


def argument_key(obj, ref_key=None):
    """The JSON-able key an argument contributes.

    Parameters
    ----------
    obj : object
        A task's argument: a number, string, None, a NumPy array, a list, tuple or dict
        of them, a dataclass of them, or an object with a ``cache_key`` (a model, a
        gait), or a task's result handle.
    ref_key : callable, optional
        ``ref_key(obj)`` returns the key of a result handle, or None for other objects.

    Returns
    -------
    object
        Plain JSON types.

    Raises
    ------
    NotKeyable
        For other objects (a function, an open file, an untyped object).
    """
    if ref_key is not None:
        k = ref_key(obj)
        if k is not None:
            return ["task", k]
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, (int, np.integer)) and not isinstance(obj, bool):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return ["f", _number(obj)]
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        if a.dtype == object:
            return ["objects", list(a.shape), [argument_key(v, ref_key) for v in a.ravel()]]
        return ["array", str(a.dtype), list(a.shape), hashlib.sha256(a.tobytes()).hexdigest()]
    key = getattr(obj, "cache_key", None)
    if key is not None and not callable(key):
        return [type(obj).__name__, argument_key(key, ref_key)]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return [f"{type(obj).__module__}.{type(obj).__qualname__}",
                {f.name: argument_key(getattr(obj, f.name), ref_key)
                 for f in dataclasses.fields(obj)}]
    if isinstance(obj, (list, tuple)):
        return [argument_key(v, ref_key) for v in obj]
    if isinstance(obj, dict):
        return {str(k): argument_key(v, ref_key) for k, v in sorted(obj.items(), key=str)}
    raise NotKeyable(f"a task argument of type {type(obj).__name__} has no key (pass "
                     "numbers, arrays, dataclasses or objects with a cache_key)")


def task_key(name: str, version: int, code: str, args=(), kwargs=None, ref_key=None) -> str:
    """The key of one call of a task (or of any result kept by its inputs).

    Parameters
    ----------
    name : str
        The task's name (module and function).
    version : int
        The task's own version.
    code : str
        Its code set (:func:`code_version`).
    args : tuple
        Positional arguments.
    kwargs : dict, optional
        Keyword arguments.
    ref_key : callable, optional
        As :func:`argument_key`.

    Returns
    -------
    str
        32 hex digits.
    """
    body = dict(task=name, version=int(version), code=code_version(code),
                args=argument_key(list(args), ref_key),
                kwargs=argument_key(dict(kwargs or {}), ref_key))
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()[:32]


# ------------------------------------------------------------------------ code
#: the code each kind of result depends on: (files or package folders, those left out,
#: those kept inside the left out), as paths relative to the packages' parent folder.
#: 'numerical': the toolkit without the report, the command line and the figures;
#: 'figures': with the figures; 'gait': the two lower layers (kept gaits); 'sweep' and
#: 'montecarlo': what decides a stored sweep's or Monte Carlo's numbers
CODE_SETS = {
    "numerical": (("biped_casadi", "gait_opt", "analysis"),
                  ("analysis/reporting", "analysis/cli", "analysis/pipeline/figures.py"), ()),
    "figures": (("biped_casadi", "gait_opt", "analysis"),
                ("analysis/reporting", "analysis/cli"), ("analysis/reporting/plots",)),
    "gait": (("biped_casadi", "gait_opt"), (), ()),
    "sweep": (tuple(f"{m}.py" for m in (
        "analysis/stability/poincare", "analysis/stability/variational",
        "biped_casadi/control/output_law", "biped_casadi/control/zero_dynamics",
        "biped_casadi/simulation/kernel", "biped_casadi/numerics", "biped_casadi/model/biped",
        "gait_opt/gait", "gait_opt/parametrisation")), (), ()),
    "montecarlo": (tuple(f"{m}.py" for m in (
        "biped_casadi/model/biped", "biped_casadi/control/output_law",
        "biped_casadi/control/zero_dynamics", "biped_casadi/control/time_varying",
        "biped_casadi/control/virtual_constraints", "biped_casadi/simulation/kernel",
        "biped_casadi/simulation/validity", "biped_casadi/simulation/outcome",
        "biped_casadi/simulation/full_order", "biped_casadi/simulation/tv_walker",
        "biped_casadi/simulation/vc_walker", "biped_casadi/simulation/terrain",
        "analysis/terrain/montecarlo", "analysis/terrain/chunks")), (), ()),
}

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
            if body and isinstance(e := body[0], ast.Expr) \
                    and isinstance(e.value, ast.Constant) and isinstance(e.value.value, str):
                node.body = body[1:] or [ast.Pass()]
        for name in _STATEMENT_FIELDS:
            children = getattr(node, name, None)
            if isinstance(children, list):
                stack.extend(c for c in children if isinstance(c, ast.AST))
    return tree


#: code_of's results in this process, by file and content; one parse at a time: CPython
#: 3.11 keeps the AST constructor's recursion depth per interpreter, so two threads
#: building syntax trees at once (ours, or another library's ``ast.literal_eval``) can
#: fail with "AST constructor recursion depth mismatch" (then the parse is tried again)
_CODE_OF: dict = {}
_PARSING = threading.Lock()


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
    return _code_of(Path(path), Path(path).read_bytes())


def _code_of(p: Path, data: bytes) -> str:
    """:func:`code_of` of the file ``p`` whose bytes are ``data``."""
    key = (str(p), hashlib.sha256(data).digest())
    with _PARSING:               # several code sets share files: each is parsed once
        for attempt in range(3):
            if key in _CODE_OF:
                break
            try:
                _CODE_OF[key] = ast.dump(_strip_docstrings(ast.parse(data, filename=str(p))),
                                         include_attributes=False)
            except SystemError:
                if attempt == 2:
                    raise
    return _CODE_OF[key]


_FILES: dict = {}


def _stat(path) -> tuple | None:
    """What changes with a file's content: size, mtime, ctime, inode (None: gone)."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino


def _python_files() -> dict:
    """The three packages' Python files: relative path -> (file, _stat, then bytes' SHA-256)."""
    out = {}
    for top in ("biped_casadi", "gait_opt", "analysis"):
        spec = importlib.util.find_spec(top)
        root = Path(spec.origin).parent if spec and spec.origin else None
        for folder, subs, names in os.walk(root) if root is not None else ():
            subs[:] = [d for d in subs if d != "__pycache__"]
            for n in names:
                if n.endswith(".py"):
                    f = Path(folder, n)
                    st, sha = _stat(f), ""
                    with contextlib.suppress(OSError):
                        sha = hashlib.sha256(f.read_bytes()).hexdigest()
                    out[f.relative_to(root.parent).as_posix()] = (f, st, sha)
    return dict(sorted(out.items()))


#: the toolkit's files as this process imports it (this module among the first): the stat of
#: each then (or since, same code), its bytes' SHA-256 then (code_files does not read again)
_IMPORTED = _python_files()
_READ: dict = {}


def _read(rel: str) -> tuple:
    """A file's code digest as first read, and whether it is of the code imported (its
    bytes the import's: a ``touch`` since, even before this read, is the same code)."""
    if rel not in _READ:
        f, st, sha = _IMPORTED[rel]
        now = d = ""
        with contextlib.suppress(OSError):                 # (removed: no digest)
            now, d = _file_digest(f, sha if _stat(f) == st else "")
        _READ[rel] = d, bool(d) and now == sha
    return _READ[rel]


def code_edited(kind: str = "numerical") -> str:
    """The first file of a code set whose code changed on disk since it was imported.

    Then the code that runs (modules imported before the change, and after it) and the
    code digest (:func:`code_version`, read from the files) may differ: its tasks are
    refused (:mod:`analysis.tasks`) until it (a Dask worker, the command) restarts.  A
    file's size, times and inode are compared (a stat of each file); one whose stat
    changed is read, and kept if its code (:func:`code_of`) is the code imported (a
    ``touch`` at any time: its new stat is then kept, one read); until this process first
    read it (:func:`code_files`), that code is known by its bytes as imported.

    Parameters
    ----------
    kind : str
        A key of :data:`CODE_SETS`.

    Returns
    -------
    str
        The file, relative to the packages' parent folder ('' if none changed).
    """
    for rel in code_files(kind):
        f, st, sha = _IMPORTED[rel]
        if (now := _stat(f)) == st:
            continue
        (d, known), same = _read(rel), False
        with contextlib.suppress(OSError):
            same = known and now is not None and _file_digest(f)[1] == d
        if not same:
            return rel
        if _stat(f) == now:                         # (not edited while read)
            _IMPORTED[rel] = f, now, sha
    return ""


def files_differing(ours: dict, theirs: dict) -> str:
    """How the first file that differs between two :func:`code_files` differs ('' if none).

    Parameters
    ----------
    ours, theirs : dict
        This run's and another process's :func:`code_files` of one code set.

    Returns
    -------
    str
        ``'a.py differs'``, ``'a.py was added'`` (in ``ours`` only) or ``'a.py was
        removed'`` (in ``theirs`` only), then how many more differ (``' (and 2 more)'``).
    """
    if not (diff := sorted(f for f in set(ours) | set(theirs) if ours.get(f) != theirs.get(f))):
        return ""
    how = "was added" if diff[0] not in theirs else "was removed" if diff[0] not in ours \
        else "differs"
    return f"{diff[0]} {how}" + (f" (and {len(diff) - 1} more)" if len(diff) > 1 else "")


def code_files(kind: str = "numerical") -> dict:
    """The files of a code set and the digest of each one's code (:func:`code_of`).

    Parameters
    ----------
    kind : str
        A key of :data:`CODE_SETS`.

    Returns
    -------
    dict
        Path relative to the packages' parent folder -> 16 hex digits; computed once
        per process, of the files there when it imported the toolkit
        (:func:`code_edited` says whether they changed since).
    """
    if kind not in CODE_SETS:
        raise ValueError(f"kind must be one of {sorted(CODE_SETS)}, got {kind!r}")
    if kind not in _FILES:
        paths, left_out, kept = CODE_SETS[kind]
        inside = lambda rel, ps: any(rel == p or rel.startswith(p + "/") for p in ps)  # noqa
        _FILES[kind] = {rel: _read(rel)[0] for rel in _IMPORTED
                        if inside(rel, paths) and not (inside(rel, left_out)
                                                       and not inside(rel, kept))}
        _save_digests()
    return _FILES[kind]


#: file digests kept on disk by the file's bytes (a syntax tree costs about 5 ms a file
#: to parse and dump, 0.7 s for the toolkit: once per process without this memo)
_DIGESTS: dict = {}
_DIGESTS_NEW: list = []
_DIGESTS_READ: list = []


def _digests_path() -> Path:
    return cache_dir() / f"code-digests-py{sys.version_info[0]}{sys.version_info[1]}.json"


def _file_digest(path: Path, sha: str = "") -> tuple:
    """The SHA-256 of a file's bytes and 16 hex digits of their :func:`code_of`, memoised on
    disk by the former (the file is read unless the memo holds ``sha``, its bytes')."""
    if not _DIGESTS_READ:
        _DIGESTS_READ.append(True)
        with contextlib.suppress(OSError, ValueError):
            memo = json.loads(_digests_path().read_text())
            _DIGESTS.update(memo if isinstance(memo, dict) else {})
    if not (isinstance(d := _DIGESTS.get(sha), str) and len(d) == 16):
        sha = hashlib.sha256(data := path.read_bytes()).hexdigest()
        if not (isinstance(d := _DIGESTS.get(sha), str) and len(d) == 16):
            d = _DIGESTS[sha] = hashlib.sha256(_code_of(path, data).encode()).hexdigest()[:16]
            _DIGESTS_NEW.append(sha)
    return sha, d


def _save_digests():
    """Write the memo when this process added to it (atomically; a failure is harmless)."""
    if _DIGESTS_NEW:
        # edits add entries: past 5000, only the files of this process are kept
        memo = _DIGESTS if len(_DIGESTS) <= 5000 else {
            k: _DIGESTS[k] for k in _DIGESTS_NEW}
        _DIGESTS_NEW.clear()
        with contextlib.suppress(OSError):
            _digests_path().parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(_digests_path(), json.dumps(memo, sort_keys=True).encode())


_VERSIONS: dict = {}


def code_version(kind: str = "numerical") -> str:
    """The version of a set of code: the one code digest of the toolkit.

    The SHA-256 of the CasADi and NumPy versions and of each file of the set with the
    digest of its syntax tree without docstrings (:func:`code_files`).

    Parameters
    ----------
    kind : str
        A key of :data:`CODE_SETS` ('numerical': the toolkit without the report,
        figures and command line; 'figures': with the figures).

    Returns
    -------
    str
        64 hex digits; computed once per process.
    """
    if kind not in _VERSIONS:
        import casadi
        h = hashlib.sha256(f"casadi {casadi.__version__} numpy {np.__version__}".encode())
        for rel, d in code_files(kind).items():
            h.update(f"{rel} {d}\n".encode())
        _VERSIONS[kind] = h.hexdigest()
    return _VERSIONS[kind]


# ------------------------------------------------------------------ the store
#: what :meth:`ResultStore.read` returns for a key with no usable result
MISSING = object()


class ResultStore:
    """Results kept between runs: ``<cache>/tasks/<key[:2]>/<key>.pkl``.

    Each file holds the result's name, its value and the seconds it took.  A file that
    cannot be read is treated as absent (the result is computed again and replaces it);
    a folder that cannot be written keeps nothing, without failing the run.  A result
    kept in a format of its own (a gait file, a sweep folder) lives at :meth:`path`
    with its own suffix.

    Parameters
    ----------
    folder : str, Path or False, optional
        The cache folder (default :func:`cache_dir`); False keeps nothing.
    """

    def __init__(self, folder=None):
        self.enabled = folder is not False
        self.root = cache_dir(None if folder is False else folder) / "tasks"

    def path(self, key: str, suffix: str = ".pkl") -> Path:
        """The file (or folder) of one key.

        Parameters
        ----------
        key : str
            A key (:func:`task_key`).
        suffix : str
            '.pkl' for the store's own entries; another for a file of its own format,
            '' for a folder.

        Returns
        -------
        Path
        """
        return self.root / key[:2] / f"{key}{suffix}"

    def empty(self) -> bool:
        """Whether nothing is kept (or nothing can be): every result will be computed.

        Returns
        -------
        bool
        """
        with contextlib.suppress(OSError):
            return not (self.enabled and any(self.root.iterdir()))
        return True

    def read(self, key: str):
        """The kept record of a key.

        Parameters
        ----------
        key : str
            A key.

        Returns
        -------
        dict or MISSING
            ``name``, ``value``, ``seconds``.
        """
        if not self.enabled:
            return MISSING
        try:
            rec = pickle.loads(self.path(key).read_bytes())
        except Exception:            # noqa: BLE001 - absent, or damaged: computed again
            return MISSING
        return rec if isinstance(rec, dict) and "value" in rec else MISSING

    def write(self, key: str, name: str, value, seconds: float = 0.0) -> bool:
        """Keep a result (atomically: the file is complete or absent).

        Parameters
        ----------
        key, name : str
            Its key and name.
        value : object
            The result (picklable).
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
