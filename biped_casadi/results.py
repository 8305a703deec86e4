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
    ``{"dict": False}`` (large logs, CasADi objects) are left out of ``to_dict()``.
    """

    SUCCESS: tuple = ()

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


def internal(**kw):
    """A dataclass field left out of ``Result.to_dict()`` (logs, CasADi objects)."""
    md = dict(kw.pop("metadata", {}))
    md["dict"] = False
    return dataclasses.field(metadata=md, **kw)
