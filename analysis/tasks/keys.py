"""Keys of tasks: what a result depends on, and the version of the code that computes it.

A task's key is the digest of its name, its own version, the version of the numerical
code (:func:`code_version`) and the keys of its arguments (:func:`argument_key`).  An
argument that is the result of another task contributes that task's key (so the keys of
a whole graph are known before anything runs); a value contributes its content.

The code version is a digest of the *syntax trees* of the numerical modules with their
docstrings removed: editing a docstring, a comment or the layout of a line, or anything
in the report, the figures or the command line, keeps every numerical result; changing
a number or a statement of the numerical code gives new keys (the old results stay on
disk, unused).
"""
from __future__ import annotations

import dataclasses
import hashlib
import importlib.util
import json
import math
from pathlib import Path

import numpy as np

from biped_casadi.caching import code_of

__all__ = ["code_version", "argument_key", "task_key", "CODE_SETS", "NotKeyable"]

#: the code each kind of task depends on: (packages, folders or files left out, and kept
#: inside those), as paths relative to the packages' parent folder; the report, the
#: command line and (for numbers) the figures are not part of any numerical result
CODE_SETS = {
    "numerical": (("biped_casadi", "gait_opt", "analysis"),
                  ("analysis/reporting", "analysis/cli", "analysis/pipeline/figures.py"), ()),
    "figures": (("biped_casadi", "gait_opt", "analysis"),
                ("analysis/reporting", "analysis/cli"), ("analysis/reporting/plots",)),
}

_VERSIONS: dict = {}


class NotKeyable(TypeError):
    """An argument of a task whose content cannot be keyed (not a typed value)."""


def _package_root(name: str) -> Path | None:
    spec = importlib.util.find_spec(name)
    return Path(spec.origin).parent if spec and spec.origin else None


def code_version(kind: str = "numerical") -> str:
    """The version of the code a kind of task runs.

    The SHA-256 of its modules' syntax trees without docstrings, and of the CasADi and
    NumPy versions.

    Parameters
    ----------
    kind : str
        A key of :data:`CODE_SETS` ('numerical': the toolkit without the report, figures
        and command line; 'figures': with the figures).

    Returns
    -------
    str
        64 hex digits; computed once per process.
    """
    if kind not in CODE_SETS:
        raise ValueError(f"kind must be one of {sorted(CODE_SETS)}, got {kind!r}")
    if kind not in _VERSIONS:
        import casadi
        packages, left_out, kept = CODE_SETS[kind]
        h = hashlib.sha256(f"casadi {casadi.__version__} numpy {np.__version__}".encode())
        for name in packages:
            root = _package_root(name)
            if root is None:
                continue
            for f in sorted(root.rglob("*.py")):
                rel = f.relative_to(root.parent).as_posix()
                inside = lambda ps: any(rel == p or rel.startswith(p + "/") for p in ps)  # noqa
                if inside(left_out) and not inside(kept):
                    continue
                h.update(rel.encode())
                h.update(code_of(f).encode())
        _VERSIONS[kind] = h.hexdigest()
    return _VERSIONS[kind]


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


def task_key(name: str, version: int, code: str, args, kwargs, ref_key=None) -> str:
    """The key of one call of a task.

    Parameters
    ----------
    name : str
        The task's name (module and function).
    version : int
        The task's own version.
    code : str
        Its kind of code (:func:`code_version`).
    args : tuple
        Positional arguments.
    kwargs : dict
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
                kwargs=argument_key(dict(kwargs), ref_key))
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()[:32]
