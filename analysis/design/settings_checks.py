"""Checks of the design searches' settings: counts, positive numbers, gait fields."""
from __future__ import annotations

import dataclasses

from biped_casadi.numerics import as_count, as_number
from gait_opt import GaitOptions

__all__ = ["check_fields", "check_gait_fields"]


def check_fields(obj, integers=(), numbers=(), low: int = 1) -> None:
    """Refuse settings fields that are not integers >= ``low`` or positive finite numbers
    (ValueError naming the field); numpy integers become ints.

    Parameters
    ----------
    obj : dataclass
        Frozen settings.
    integers, numbers : tuple of str
        The fields to check as counts and as positive numbers (None skipped).
    low : int
        The least count.
    """
    for name in integers:
        object.__setattr__(obj, name, as_count(getattr(obj, name), name, low))
    for name in numbers:
        if getattr(obj, name) is not None:
            object.__setattr__(obj, name, as_number(getattr(obj, name), name, positive=True))


def check_gait_fields(gait, name: str = "gait") -> dict:
    """``gait`` checked: a dict of known GaitOptions fields with valid values.

    Parameters
    ----------
    gait : dict
        GaitOptions fields by name.
    name : str
        The argument's name, used in the error message.

    Returns
    -------
    dict
        ``gait``.

    Raises
    ------
    ValueError
        Naming the field that is unknown or has an invalid value.
    """
    if not isinstance(gait, dict):
        raise ValueError(f"{name} must be a dict of GaitOptions fields, got "
                         f"{type(gait).__name__}")
    known = {f.name for f in dataclasses.fields(GaitOptions)}
    unknown = sorted(set(gait) - known)
    if unknown:
        raise ValueError(f"{name}: {unknown[0]!r} is not a GaitOptions field")
    GaitOptions(**gait)                  # its own checks, naming the field
    return gait
