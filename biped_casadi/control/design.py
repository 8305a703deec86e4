"""A controller design: which law runs on which gait, with which outputs and gains.

:class:`Design` is the one type every analysis, walker, simulator, Monte Carlo, export
and command accepts.  A time-varying design is the output matrix M1 of v = [M1, I] q
and the time the correction v_c rejoins the reference; virtual constraints have no M1.
The output gains (Kp, Kd, eps of eq. 13) do not change how the controller walks on its
own model (the closed loop is its zero dynamics) but matter with a model error, with
saturation and for an exported controller, so they are part of the design.
"""
from __future__ import annotations


import numpy as np

from ..caching import digest
from .output_law import Gains, check_M1, check_rejoin
from .reference import Reference, require_reference, require_same_robot
from .time_varying import PAPER_REJOIN, TimeVaryingController
from .virtual_constraints import VirtualConstraintController

__all__ = ["Design"]


class Design:
    """One controller on one gait (immutable).

    Parameters
    ----------
    M1 : array_like or None
        One number per actuated joint: the time-varying outputs v = [M1, I] q; None:
        virtual constraints fitted to the gait.
    rejoin : float
        When v_c rejoins the reference, fraction of T, in (0, 0.75] (time-varying only;
        the paper: 1/2).
    gait : Reference, optional
        The gait the design runs on (a design without one is completed by the function
        it is given to, with the gait given there).
    gains : Gains, tuple or dict, optional
        (Kp, Kd, eps) of eq. (13), all three, or a dict of some of them by name; default
        ``Gains()``.

    Examples
    --------
    >>> Design.tv(gait, [-10, 7.5, 10, -5], rejoin=0.75)   # doctest: +SKIP
    >>> Design.vc(gait)                                     # doctest: +SKIP
    """

    __slots__ = ("M1", "rejoin", "gait", "gains")

    def __init__(self, M1=None, rejoin: float = PAPER_REJOIN, gait: Reference | None = None,
                 gains=None):
        if gait is not None:
            require_reference(gait)
        if M1 is not None:
            try:
                M1 = np.atleast_1d(np.asarray(M1, dtype=float))
            except (TypeError, ValueError):
                raise ValueError(f"M1 must be numbers (one per torque), got {M1!r}") from None
            if gait is not None and M1.size != gait.model.nu:
                raise ValueError(f"M1 must have {gait.model.nu} components (one per torque) "
                                 f"for {gait.model.params.name}, got {M1.size}")
            M1 = tuple(check_M1(M1, M1.size).tolist())
        rejoin = check_rejoin(rejoin)
        gains = _gains(gains)
        for k, v in (("M1", M1), ("rejoin", rejoin), ("gait", gait), ("gains", gains)):
            object.__setattr__(self, k, v)

    def __setattr__(self, name, value):
        raise AttributeError("a Design is immutable: use .replace(...)")

    def __reduce__(self):
        return (Design, (self.M1, self.rejoin, self.gait, self.gains))

    # ------------------------------------------------------------- doors
    @classmethod
    def tv(cls, gait, M1, rejoin: float = PAPER_REJOIN, gains=None) -> "Design":
        """A time-varying design on ``gait``.

        Parameters
        ----------
        gait : Reference
            The gait.
        M1 : array_like
            The outputs.
        rejoin : float
            Rejoin time of v_c, fraction of T.
        gains : Gains or tuple, optional
            (Kp, Kd, eps).

        Returns
        -------
        Design
        """
        if M1 is None:
            raise ValueError("M1: give one number per torque (Design.vc(gait) for virtual "
                             "constraints)")
        return cls(M1, rejoin, gait, gains)

    @classmethod
    def vc(cls, gait, gains=None) -> "Design":
        """Virtual constraints fitted to ``gait``.

        Parameters
        ----------
        gait : Reference
            The gait.
        gains : Gains or tuple, optional
            (Kp, Kd, eps).

        Returns
        -------
        Design
        """
        return cls(None, PAPER_REJOIN, gait, gains)

    @classmethod
    def of(cls, design, gait=None) -> "Design":
        """A design from what callers pass: a Design, None (virtual constraints) or an M1.

        Parameters
        ----------
        design : Design, None or array_like
            The design.
        gait : Reference, optional
            The gait to put it on when it has none (a design on another gait is refused).

        Returns
        -------
        Design
        """
        d = design if isinstance(design, Design) else cls(design, gait=gait)
        if gait is None:
            return d
        if d.gait is None:
            return d.replace(gait=gait)
        if d.gait is not gait and _key(d.gait) != _key(gait):
            raise ValueError("design: made for another gait than the one given")
        return d

    @classmethod
    def require(cls, design) -> "Design":
        """``design`` checked to be a :class:`Design` on its gait.

        Parameters
        ----------
        design : Design
            The design.

        Returns
        -------
        Design

        Raises
        ------
        ValueError
            Naming 'design' when it is not a Design or has no gait.
        """
        if not isinstance(design, Design) or design.gait is None:
            raise ValueError("design: a Design on its gait is needed (Design.tv(gait, M1), "
                             "Design.vc(gait) or Design.of(M1, gait))")
        return design

    def replace(self, **changes) -> "Design":
        """A copy with some fields changed.

        Parameters
        ----------
        **changes
            ``M1``, ``rejoin``, ``gait`` or ``gains``.

        Returns
        -------
        Design
        """
        f = dict(M1=self.M1, rejoin=self.rejoin, gait=self.gait, gains=self.gains)
        unknown = set(changes) - set(f)
        if unknown:
            raise ValueError(f"Design has no field {sorted(unknown)[0]!r}")
        f.update(changes)
        return Design(**f)

    # ------------------------------------------------------------- views
    @property
    def controller(self) -> str:
        """'tv' (time-varying outputs) or 'vc' (virtual constraints)."""
        return "vc" if self.M1 is None else "tv"

    @property
    def model(self):
        """The gait's robot model."""
        return self._gait().model

    def _gait(self, gait=None):
        g = gait if gait is not None else self.gait
        if g is None:
            raise ValueError("design: no gait (use Design.tv(gait, ...) or pass a gait)")
        return g

    def controller_for(self, gait=None):
        """The closed-loop controller of the design on its gait (or on ``gait``).

        Parameters
        ----------
        gait : Reference, optional
            Default: the design's own gait.

        Returns
        -------
        TimeVaryingController or VirtualConstraintController
        """
        g = self._gait(gait)
        if self.M1 is None:
            return VirtualConstraintController(g, gains=self.gains)
        return TimeVaryingController(g, np.array(self.M1), self.gains, self.rejoin)

    def check_model(self, model):
        """Raise ``ValueError`` unless the design's gait is made for ``model``.

        Parameters
        ----------
        model : BipedModel
            The robot.
        """
        if self.gait is not None:
            require_same_robot(model, self.gait)

    def to_dict(self) -> dict:
        """The design in plain JSON types (without the gait, which has its own file).

        Returns
        -------
        dict
            ``controller``, ``M1`` (list, or None), ``rejoin``, ``gains`` (Kp, Kd, eps)
            and ``gait`` (the gait's key, or None).
        """
        return dict(controller=self.controller,
                    M1=None if self.M1 is None else list(self.M1),
                    rejoin=self.rejoin, gains=self.gains.to_dict(),
                    gait=None if self.gait is None else _key(self.gait))

    @property
    def cache_key(self) -> str:
        """What the design's results depend on (the gait by its own key)."""
        if self.gait is not None and getattr(self.gait, "cache_key", None) is None:
            raise AttributeError("the design's gait has no cache_key")
        return digest(self.to_dict())

    def label(self) -> str:
        """A short description of the design.

        Returns
        -------
        str
            e.g. 'M1 = [-10, 7.5, 10, -5], v_c rejoins at 0.5 T'.
        """
        if self.M1 is None:
            return "virtual constraints"
        return (f"M1 = [{', '.join(f'{v:.4g}' for v in self.M1)}], v_c rejoins at "
                f"{self.rejoin:g} T")

    def __eq__(self, other):
        return isinstance(other, Design) and self.to_dict() == other.to_dict()

    def __hash__(self):
        return hash(self.cache_key)

    def __repr__(self):
        gait = "" if self.gait is None else f", gait T={self.gait.T:.4g} s"
        if self.M1 is None:
            return f"Design.vc({self.gains!r}{gait})"
        return f"Design(M1={list(self.M1)}, rejoin={self.rejoin:g}{gait})"


def _gains(gains) -> Gains:
    """``gains`` as a :class:`Gains`: None (the defaults), a Gains, a mapping by name or
    the three numbers (Kp, Kd, eps)."""
    if gains is None or isinstance(gains, Gains):
        return Gains() if gains is None else gains
    if isinstance(gains, dict):
        unknown = sorted(set(gains) - {"Kp", "Kd", "eps"})
        if unknown:
            raise ValueError(f"gains: unknown gain {unknown[0]!r} (Kp, Kd, eps)")
        return Gains(**gains)
    if isinstance(gains, (str, bytes)) or not hasattr(gains, "__len__") or len(gains) != 3:
        raise ValueError(f"gains must be a Gains or the three numbers (Kp, Kd, eps), "
                         f"got {gains!r}")
    return Gains(*gains)


def _key(gait):
    return getattr(gait, "cache_key", None) or id(gait)
