"""Result objects, in the style of :class:`scipy.optimize.OptimizeResult`.

Every computation of the toolkit that can end in more than one way returns a dataclass
that mixes in :class:`Result`: named fields, a ``status`` string, a human ``message``,
a boolean ``success`` (what it means is said by each class), and ``to_dict()`` giving
plain JSON types (the command line prints exactly that).
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

__all__ = ["Result", "json_safe"]


def json_safe(o):
    """Plain JSON types for ``o``.

    numpy scalars and arrays are unpacked, complex numbers become ``[re, im]`` pairs,
    non-finite floats become ``None``, paths strings, dict keys strings, and objects
    with a ``to_dict()`` method their dictionary.

    Parameters
    ----------
    o : object
        Anything built from dicts, lists, tuples, numbers, numpy values and results.

    Returns
    -------
    object
        The same structure in JSON types (``json.dumps(..., allow_nan=False)`` works).
    """
    if hasattr(o, "to_dict") and callable(o.to_dict):
        return json_safe(o.to_dict())
    if isinstance(o, dict):
        return {str(k): json_safe(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [json_safe(v) for v in o]
    if isinstance(o, np.ndarray):
        return json_safe(o.tolist())
    if isinstance(o, (bool, np.bool_)):
        return bool(o)
    if isinstance(o, (complex, np.complexfloating)):
        return [json_safe(float(o.real)), json_safe(float(o.imag))]
    if isinstance(o, (float, np.floating)):
        return float(o) if math.isfinite(o) else None
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, Path):
        return str(o)
    return o


class Result:
    """Mixin for result dataclasses: ``success``, ``to_dict()``.

    A subclass is a dataclass with at least the fields ``status`` and ``message``, and
    sets ``SUCCESS`` to the statuses that count as success.  Fields whose metadata has
    ``{"dict": False}`` (large logs, CasADi objects) are left out of ``to_dict()`` and of
    the repr, which shows every other field briefly (large arrays and lists by their size)
    unless the subclass writes its own.
    """

    SUCCESS: tuple = ()

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        # a repr a notebook can show: put in the class before @dataclass, which then keeps
        # it (a class that writes its own __repr__ keeps that one)
        if "__repr__" not in cls.__dict__:
            cls.__repr__ = _brief_repr

    @property
    def success(self) -> bool:
        """Whether ``status`` is one of the class's successful statuses."""
        return self.status in self.SUCCESS

    def to_dict(self) -> dict:
        """The result in plain JSON types (what ``--json`` prints).

        Returns
        -------
        dict
            Every field not marked internal, through :func:`json_safe`, plus
            ``success``.
        """
        out = {}
        for f in dataclasses.fields(self):
            if f.metadata.get("dict", True):
                out[f.name] = json_safe(getattr(self, f.name))
        out["success"] = self.success
        return out


#: the longest repr of one field in a result's repr (longer ones are summarised)
_FIELD_CHARS = 100


def _brief(v) -> str:
    """One field for a result's repr: numbers as Python numbers, small arrays and lists as
    short lists, large ones by their size, long text cut."""
    if isinstance(v, Result):
        return f"{type(v).__name__}(status={getattr(v, 'status', '?')!r}, ...)"
    if isinstance(v, (bool, np.bool_)):
        return repr(bool(v))
    if isinstance(v, (np.integer, int)):
        return repr(int(v))
    if isinstance(v, (np.floating, float)):
        return repr(float(v))
    if isinstance(v, (np.complexfloating, complex)):
        return repr(complex(v))
    if isinstance(v, np.ndarray):
        if v.size <= 8 and v.dtype.kind in "biufc":
            text = _numbers(v.tolist())
            if len(text) <= _FIELD_CHARS:
                return text
        return f"<array {'x'.join(map(str, v.shape))} {v.dtype}>"
    if isinstance(v, str):
        return repr(v) if len(v) <= _FIELD_CHARS else repr(v[:_FIELD_CHARS - 20] + "...")
    if isinstance(v, (list, tuple, dict)):
        text = repr(json_safe(v))
        if len(text) <= _FIELD_CHARS:
            return text
        kind = {list: "list", tuple: "tuple", dict: "dict"}[type(v)] \
            if type(v) in (list, tuple, dict) else type(v).__name__
        return f"<{kind} of {len(v)}>"
    text = repr(v)
    return text if len(text) <= _FIELD_CHARS else f"<{type(v).__name__}>"


def _numbers(v) -> str:
    """Nested lists of numbers, each to 6 significant digits."""
    if isinstance(v, list):
        return "[" + ", ".join(_numbers(x) for x in v) + "]"
    if isinstance(v, complex):
        return f"({v.real:.6g}{v.imag:+.6g}j)"
    return f"{v:.6g}" if isinstance(v, float) else repr(v)


def _brief_repr(self) -> str:
    """``Name(field=value, ...)`` with every field in a few characters (:func:`_brief`),
    internal fields (logs, CasADi objects) left out: the full values are the attributes
    and ``to_dict()``."""
    fields = [f for f in dataclasses.fields(self) if f.repr and f.metadata.get("dict", True)]
    inner = ", ".join(f"{f.name}={_brief(getattr(self, f.name))}" for f in fields)
    return f"{type(self).__name__}({inner})"


def internal(**kw):
    """A dataclass field left out of ``Result.to_dict()`` (logs, CasADi objects)."""
    md = dict(kw.pop("metadata", {}))
    md["dict"] = False
    return dataclasses.field(metadata=md, **kw)
