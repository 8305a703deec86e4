"""Speed profiles on a gait family: the speeds of the steps, the gait of each, and the
design of each (an M1 scheduled over speed) (docs: theory, "Speed changes").

A profile is one speed per step (m/s): given (:func:`check_profile`) or a ramp
(:func:`ramp_speeds`, up from v1 to v2 and back down by dv per step).  Each speed's gait
comes from a :class:`gait_opt.GaitFamily` (:func:`profile_gaits`): the member at that
speed, or between members the family's interpolant polished to an exact orbit
(:meth:`gait_opt.GaitFamily.gait_at`).  The designs (:func:`profile_designs`) are
virtual constraints fitted to each gait, or time-varying outputs with one M1 for all
speeds or an :class:`M1Schedule`: M1 (and the rejoin time of v_c) given at a few speeds,
interpolated linearly in speed between them.

The schedule file (JSON)::

    {"format": "biped-casadi-m1-schedule", "rejoin": 0.75,
     "points": [{"speed": 0.5, "M1": [a, b, c, d]},
                {"speed": 0.75, "M1": [a, b, c, d], "rejoin": 0.5}, ...]}

``points`` lists one or more speeds (m/s, strictly increasing after sorting, each once)
with their M1 (one number per torque); a point's ``rejoin`` (fraction of T, in
(0, 0.75]) overrides the file's (default 0.5).  Between two points M1 and rejoin are
interpolated linearly; a schedule of one point is that design at every speed; a speed
outside the points' range is refused.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

from biped_casadi import Design
from biped_casadi.control.output_law import check_M1, check_rejoin
from biped_casadi.files import read_text_file, write_text_atomic
from gait_opt import GaitFamily, speed_range

__all__ = ["M1Schedule", "SCHEDULE_FORMAT", "ramp_speeds", "check_profile", "profile_gaits",
           "profile_designs", "GaitSource"]

#: the ``format`` of an M1 schedule file
SCHEDULE_FORMAT = "biped-casadi-m1-schedule"
#: two speeds closer than this (m/s) are the same
SPEED_TOL = 1e-9


# ------------------------------------------------------------------------ speeds
def ramp_speeds(v1: float, v2: float, dv: float, hold: int = 0) -> np.ndarray:
    """A ramp: v1, v1 + dv, ..., v2, v2 - dv, ..., v1, then ``hold`` more steps at v1.

    Parameters
    ----------
    v1, v2 : float
        The lowest and the highest speed, m/s (0 < v1 < v2, v2 - v1 a whole number of
        dv).
    dv : float
        The change per step, m/s.
    hold : int
        Steps at v1 after the ramp.

    Returns
    -------
    numpy.ndarray
        One speed per step (2 (v2 - v1) / dv + 1 + hold of them).

    Raises
    ------
    ValueError
        Naming 'speeds' (empty, reversed, non-finite, not a whole number of steps) or
        'hold'.
    """
    if isinstance(hold, bool) or not isinstance(hold, (int, np.integer)) or hold < 0:
        raise ValueError(f"hold must be a non-negative integer, got {hold!r}")
    up = speed_range(v1, v2, dv)
    return np.r_[up, up[-2::-1], np.full(int(hold), up[0])]


def check_profile(speeds, hold: int = 0) -> np.ndarray:
    """A profile of per-step speeds checked: non-empty, finite, positive.

    Parameters
    ----------
    speeds : sequence of float
        One speed per step, m/s.
    hold : int
        Steps added at the last speed.

    Returns
    -------
    numpy.ndarray

    Raises
    ------
    ValueError
        Naming 'speeds' or 'hold'.
    """
    if isinstance(hold, bool) or not isinstance(hold, (int, np.integer)) or hold < 0:
        raise ValueError(f"hold must be a non-negative integer, got {hold!r}")
    try:
        v = np.array(speeds, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError("speeds must be numbers (m/s), one per step") from None
    if v.size == 0:
        raise ValueError("speeds: the profile is empty (give one speed per step)")
    if not np.all(np.isfinite(v)):
        raise ValueError("speeds must be finite numbers (m/s)")
    if np.any(v <= 0):
        raise ValueError(f"speeds must be positive (m/s), got {v[v <= 0][0]:g}")
    return np.r_[v, np.full(int(hold), v[-1])]


# ------------------------------------------------------------------------- gaits
@dataclass
class GaitSource:
    """Where the gait of one speed of a profile came from.

    Parameters
    ----------
    speed : float
        m/s.
    source : str
        'member' (the family's gait at that speed) or 'interpolated' (the interpolant
        polished to an exact orbit).
    status : str
        :class:`gait_opt.FamilyGait`'s status ('member', 'ok' or 'violates': a constraint
        of the gait problem exceeded on the dense grid).
    interpolant_residual : float
        How far the interpolant was from an orbit before the polish (0 for a member).
    orbit_residual : float
        Of the gait used.
    """
    speed: float
    source: str
    status: str
    interpolant_residual: float
    orbit_residual: float

    def to_dict(self) -> dict:
        """The fields by name.

        Returns
        -------
        dict
        """
        return dict(speed=self.speed, source=self.source, status=self.status,
                    interpolant_residual=self.interpolant_residual,
                    orbit_residual=self.orbit_residual)


def profile_gaits(family: GaitFamily, speeds) -> tuple:
    """The gait of every step of a profile, from a family.

    Parameters
    ----------
    family : GaitFamily
        The family.
    speeds : sequence of float
        One speed per step, m/s, within the family's members' range.

    Returns
    -------
    gaits : list of Gait
        One per step (the same object for equal speeds).
    sources : list of GaitSource
        One per distinct speed, in order of first appearance.

    Raises
    ------
    ValueError
        Naming 'speeds' for a speed outside the family, or when the polish fails.
    """
    v = check_profile(speeds)
    members = family.member_speeds
    if members.size == 0:
        raise ValueError("family: it has no members")
    lo, hi = float(members.min()), float(members.max())
    out = [s for s in v if not lo - SPEED_TOL <= s <= hi + SPEED_TOL]
    if out:
        raise ValueError(f"speeds: {out[0]:g} m/s is outside the family ({lo:g} to "
                         f"{hi:g} m/s)")
    found, sources = {}, []
    for s in v:
        key = round(float(s), 9)
        if key in found:
            continue
        hit = np.flatnonzero(np.abs(members - s) <= SPEED_TOL)
        if hit.size:
            g = family.gaits[int(hit[0])]
            src = GaitSource(float(members[hit[0]]), "member", "member", 0.0,
                             float(g.orbit_residual()["worst"]))
        else:
            r = family.gait_at(float(s))
            if r.status == "failed" or r.gait is None:
                raise ValueError(f"speeds: no gait at {s:g} m/s from the family "
                                 f"({r.message})")
            g = r.gait
            src = GaitSource(float(s), "interpolated", r.status,
                             float(r.interpolant_residual), float(r.orbit_residual))
        found[key] = g
        sources.append(src)
    return [found[round(float(s), 9)] for s in v], sources


# ------------------------------------------------------------------------ designs
@dataclass(frozen=True)
class M1Schedule:
    """M1 and the rejoin time of v_c at a few speeds, interpolated linearly in speed.

    Parameters
    ----------
    speeds : tuple of float
        Strictly increasing, m/s.
    M1 : tuple of tuple of float
        One M1 per speed (one number per torque each).
    rejoin : tuple of float
        One rejoin time per speed, fraction of T in (0, 0.75].
    """
    speeds: tuple
    M1: tuple
    rejoin: tuple

    def __post_init__(self):
        v = np.asarray(self.speeds, float)
        if v.ndim != 1 or v.size == 0:
            raise ValueError("schedule: give at least one speed")
        if not np.all(np.isfinite(v)) or np.any(v <= 0):
            raise ValueError("schedule: speeds must be positive finite numbers (m/s)")
        if np.any(np.diff(v) <= SPEED_TOL):
            raise ValueError("schedule: speeds must be strictly increasing (each once)")
        rows = [np.atleast_1d(np.asarray(r, float)) for r in self.M1]
        M = np.asarray(rows) if len({r.shape for r in rows}) == 1 else np.zeros(0)
        if M.ndim != 2 or len(M) != v.size:
            raise ValueError(f"schedule: one M1 per speed ({v.size}), each a list of "
                             "numbers of one length")
        for row in M:
            check_M1(row, M.shape[1])
        if len(self.rejoin) != v.size:
            raise ValueError(f"schedule: one rejoin per speed ({v.size})")
        for r in self.rejoin:
            check_rejoin(r, "schedule: rejoin")
        object.__setattr__(self, "speeds", tuple(map(float, v)))
        object.__setattr__(self, "M1", tuple(tuple(map(float, r)) for r in M))
        object.__setattr__(self, "rejoin", tuple(map(float, self.rejoin)))

    @classmethod
    def constant(cls, M1, rejoin: float = 0.5) -> "M1Schedule":
        """One design for every speed.

        Parameters
        ----------
        M1 : array_like
            The outputs.
        rejoin : float
            Rejoin time of v_c, fraction of T.

        Returns
        -------
        M1Schedule
        """
        return cls((1.0,), (tuple(np.asarray(M1, float).ravel()),), (float(rejoin),))

    @property
    def is_constant(self) -> bool:
        """One point: the same design at every speed."""
        return len(self.speeds) == 1

    def at(self, speed: float) -> tuple:
        """(M1, rejoin) at a speed, interpolated linearly between the points.

        Parameters
        ----------
        speed : float
            m/s, within the points' range (any speed for one point).

        Returns
        -------
        tuple
            (numpy.ndarray M1, float rejoin).

        Raises
        ------
        ValueError
            Naming 'speed' outside the range.
        """
        M, r = np.asarray(self.M1), np.asarray(self.rejoin)
        if self.is_constant:
            return M[0].copy(), float(r[0])
        v = np.asarray(self.speeds)
        s = float(speed)
        if not (math.isfinite(s) and v[0] - SPEED_TOL <= s <= v[-1] + SPEED_TOL):
            raise ValueError(f"speed: {s:.6g} m/s is outside the schedule ({v[0]:g} to "
                             f"{v[-1]:g} m/s)")
        s = min(max(s, v[0]), v[-1])
        return (np.array([np.interp(s, v, M[:, j]) for j in range(M.shape[1])]),
                float(np.interp(s, v, r)))

    def to_dict(self) -> dict:
        """The schedule in its file's form (module docstring).

        Returns
        -------
        dict
        """
        return dict(format=SCHEDULE_FORMAT,
                    points=[dict(speed=s, M1=list(m), rejoin=r)
                            for s, m, r in zip(self.speeds, self.M1, self.rejoin)])

    def save(self, path):
        """Write the schedule file, atomically.

        Parameters
        ----------
        path : str or Path

        Returns
        -------
        Path
        """
        return write_text_atomic(path, json.dumps(self.to_dict(), indent=1) + "\n")

    @classmethod
    def from_dict(cls, d, where: str = "schedule") -> "M1Schedule":
        """A schedule from its file's form.

        Parameters
        ----------
        d : dict
            As :meth:`to_dict` (``format`` optional; ``rejoin`` per point or for all).
        where : str
            The name used in messages.

        Returns
        -------
        M1Schedule

        Raises
        ------
        ValueError
            Naming ``where`` and what is wrong.
        """
        if not isinstance(d, dict):
            raise ValueError(f"{where}: expected a JSON object with 'points'")
        if d.get("format", SCHEDULE_FORMAT) != SCHEDULE_FORMAT:
            raise ValueError(f"{where}: format must be {SCHEDULE_FORMAT!r}, got "
                             f"{d.get('format')!r}")
        pts = d.get("points")
        if not isinstance(pts, list) or not pts:
            raise ValueError(f"{where}: 'points' must be a non-empty list of "
                             "{speed, M1[, rejoin]}")
        default = d.get("rejoin", 0.5)
        try:
            pts = sorted(pts, key=lambda p: float(p["speed"]))
            speeds = tuple(float(p["speed"]) for p in pts)
            M1 = tuple(tuple(float(x) for x in p["M1"]) for p in pts)
            rejoin = tuple(float(p.get("rejoin", default)) for p in pts)
        except (TypeError, KeyError, ValueError, AttributeError):
            raise ValueError(f"{where}: each point needs a number 'speed' and a list of "
                             "numbers 'M1' (and optionally a number 'rejoin')") from None
        try:
            return cls(speeds, M1, rejoin)
        except ValueError as e:
            raise ValueError(f"{where}: {str(e).removeprefix('schedule: ')}") from None

    @classmethod
    def load(cls, path) -> "M1Schedule":
        """Read a schedule file (module docstring).

        Parameters
        ----------
        path : str or Path

        Returns
        -------
        M1Schedule

        Raises
        ------
        ValueError
            Naming the file and what is wrong.
        """
        text = read_text_file(path, "schedule file")
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise ValueError(f"schedule file {path} is not valid JSON: {e}") from None
        return cls.from_dict(d, f"schedule file {path}")


def profile_designs(gaits, controller: str = "tv", schedule: M1Schedule | None = None,
                    gains=None, speeds=None) -> list:
    """One design per step of a profile.

    Parameters
    ----------
    gaits : sequence of Gait
        One per step (:func:`profile_gaits`).
    controller : str
        'tv' (time-varying outputs, with ``schedule``) or 'vc' (virtual constraints).
    schedule : M1Schedule, optional
        The time-varying design over speed (required for 'tv').
    gains : Gains or tuple, optional
        (Kp, Kd, eps) of every design.
    speeds : sequence of float, optional
        The speed at which to read the schedule for each step (default each gait's
        ``speed``).

    Returns
    -------
    list of Design
        Equal gaits at equal speeds give equal designs.

    Raises
    ------
    ValueError
        Naming 'controller', 'schedule' or 'speed'.
    """
    if controller not in ("tv", "vc"):
        raise ValueError(f"controller must be 'tv' or 'vc', got {controller!r}")
    gaits = list(gaits)
    if controller == "vc":
        if schedule is not None:
            raise ValueError("schedule: applies to the time-varying controller only")
        return [Design.vc(g, gains) for g in gaits]
    if schedule is None:
        raise ValueError("schedule: the time-varying controller needs an M1 (or a schedule)")
    v = [g.speed for g in gaits] if speeds is None else list(speeds)
    if len(v) != len(gaits):
        raise ValueError("speeds: one per gait")
    out, made = [], {}
    for g, s in zip(gaits, v):
        key = (id(g), round(float(s), 9))
        if key not in made:
            M1, rejoin = schedule.at(s)
            made[key] = Design.tv(g, M1, rejoin, gains)
        out.append(made[key])
    return out
