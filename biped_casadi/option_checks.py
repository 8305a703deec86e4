"""Checks of an options dataclass's fields: numbers, counts, (low, high) pairs, flags, choices.

One :class:`FieldChecks` per validated object; each check names the field in the
object's own wording (``label`` and the phrases), so the classes' messages are kept.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["FieldChecks", "is_real"]


def is_real(v) -> bool:
    """Whether ``v`` is an int or a float (numpy floats too), not a bool.

    Parameters
    ----------
    v : object
        The value.

    Returns
    -------
    bool
    """
    return isinstance(v, (int, float)) and not isinstance(v, bool)


@dataclass(frozen=True)
class FieldChecks:
    """The field checks of one options object, raising ValueError in its wording.

    A message reads ``f"{label.format(name)} must be {phrase}, got {value!r}"``.

    Parameters
    ----------
    obj : object
        The options (a frozen dataclass: converted values are set with
        ``object.__setattr__``).
    label : str
        The field's name in a message, ``{}`` standing for it.
    positive, nonnegative : str
        Phrases of a finite number > ``low`` and >= ``low`` (``{low:g}`` may appear).
    integer : str
        Phrase of an integer in range (``{low}`` and ``{high}`` may appear).
    at_most : str or None
        Phrase of an integer above ``high``, or None: ``integer`` says it.
    pair : str
        Phrase of a (low, high) pair with 0 < low < high.
    flag : str
        Phrase of a bool.
    none : str
        Added to a phrase when None is allowed.
    real : callable
        Whether a value is a number (default :func:`is_real`: bools are not).
    """

    obj: object
    label: str
    positive: str = "a positive number"
    nonnegative: str = "a non-negative number"
    integer: str = "an integer >= {low}"
    at_most: str | None = "at most {high}"
    pair: str = "(low, high) with 0 < low < high"
    flag: str = "true or false"
    none: str = ""
    real: object = is_real

    def fail(self, name: str, phrase: str, value=None, got: bool = True):
        """Raise the ValueError of field ``name``.

        Parameters
        ----------
        name : str
            The field.
        phrase : str
            What it must be.
        value : object
            The value shown after 'got'.
        got : bool
            Show the value.
        """
        raise ValueError(f"{self.label.format(name)} must be {phrase}"
                         + (f", got {value!r}" if got else ""))

    def numbers(self, names, low: float = 0.0, strict: bool = True, none: bool = False,
                inf: bool = False, phrase: str | None = None) -> None:
        """Refuse fields that are not finite numbers > ``low`` (>= when not ``strict``).

        Parameters
        ----------
        names : iterable of str
            The fields.
        low : float
            The bound.
        strict : bool
            ``value > low``, else ``value >= low``.
        none : bool
            None is allowed (and said in the message).
        inf : bool
            ``math.inf`` is allowed too (said by ``phrase`` if at all).
        phrase : str or None
            The phrase, else the class's ``positive`` or ``nonnegative``.
        """
        for name in names:
            v = getattr(self.obj, name)
            if (v is None and none) or (inf and self.real(v) and v == math.inf):
                continue
            if not (self.real(v) and math.isfinite(v) and (v > low if strict else v >= low)):
                what = phrase or (self.positive if strict else self.nonnegative)
                self.fail(name, what.format(low=low) + (self.none if none else ""), v)

    def integers(self, names, low: int, high: int | None = None, none: bool = False,
                 phrase: str | None = None, kinds: tuple = (int,)) -> None:
        """Refuse fields that are not ints (not bools) from ``low`` to ``high``.

        Parameters
        ----------
        names : iterable of str
            The fields.
        low : int
            The least value.
        high : int or None
            The largest value, or None: no bound.
        none : bool
            None is allowed (and said in the message).
        phrase : str or None
            The phrase, else the class's ``integer``.
        kinds : tuple of type
            The integer types taken (e.g. ``(int, numpy.integer)``; bools never), kept as
            given.
        """
        for name in names:
            v = getattr(self.obj, name)
            if v is None and none:
                continue
            too_high = high is not None and isinstance(v, kinds) and v > high
            if isinstance(v, bool) or not isinstance(v, kinds) or v < low or (
                    too_high and self.at_most is None):
                self.fail(name, (phrase or self.integer).format(low=low, high=high)
                          + (self.none if none else ""), v)
            if too_high:
                self.fail(name, self.at_most.format(high=high), v)

    def pairs(self, names, none: bool = False, kinds=None, to_float: bool = False) -> None:
        """Refuse fields that are not (low, high) finite numbers with 0 < low < high.

        A valid pair is set as a tuple.

        Parameters
        ----------
        names : iterable of str
            The fields.
        none : bool
            None is allowed (silently: the value is filled in elsewhere).
        kinds : tuple of type or None
            The sequence types taken, or None: any sized object but a string.
        to_float : bool
            Set the pair as floats (else as given).
        """
        for name in names:
            given = getattr(self.obj, name)
            if given is None and none:
                continue
            ok = isinstance(given, kinds) if kinds else (
                hasattr(given, "__len__") and not isinstance(given, str))
            v = tuple(given) if ok else ()
            if len(v) != 2 or not all(is_real(x) and math.isfinite(x) for x in v) \
                    or not 0 < v[0] < v[1]:
                self.fail(name, self.pair, given)
            object.__setattr__(self.obj, name, tuple(map(float, v)) if to_float else v)

    def flags(self, names) -> None:
        """Refuse fields that are not bools.

        Parameters
        ----------
        names : iterable of str
            The fields.
        """
        for name in names:
            if not isinstance(getattr(self.obj, name), bool):
                self.fail(name, self.flag, getattr(self.obj, name))

    def choice(self, name: str, choices: tuple) -> None:
        """Refuse a field that is not one of ``choices``.

        Parameters
        ----------
        name : str
            The field.
        choices : tuple
            The values allowed.
        """
        if getattr(self.obj, name) not in choices:
            self.fail(name, f"one of {choices}", getattr(self.obj, name))
