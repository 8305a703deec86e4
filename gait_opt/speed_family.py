"""A family of reference gaits over speed, by continuation (docs/theory.md, "Gait
families").

:func:`gait_family` solves the default gait problem (SPEC section 2; any
:class:`GaitOptions`) at each speed of a grid: the first speed from the built-in guess,
every other warm-started from its neighbours (:mod:`gait_opt.continuation`: one NLP with
the speed as its parameter, IPOPT's primal-dual warm start from the secant predictor,
steps halved where a solve fails).  Every member is made an exact periodic orbit by the
same polish as :func:`optimize_gait` (:mod:`gait_opt.polish`) and checked on the same
dense grid; where an active constraint is exceeded between the nodes, its node margin
is tightened and the speed solved again, as :func:`optimize_gait` does.  Where the
family ends (no solution at the smallest step, a fold, the polish failing) the result
says where and why; where a constraint becomes active or inactive it records the event.

:meth:`GaitFamily.gait_at` gives a gait at any speed of the family's range: the members'
parameters (Bezier coefficients, T, the unactuated start x0) interpolated by a cubic
spline in the speed, then polished to an exact orbit; it reports how far the interpolant
was from the orbit and how much the polish changed it.  Files: :mod:`gait_opt.family_file`.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from biped_casadi.results import Result, internal

from .errors import GaitOptimizationError
from .family_file import family_body, read_family_file, write_family
from .gait import ORBIT_TOL, Gait
from .optimize import _solve as solve_once
from .options import GaitOptions
from .polish import polish
from .transcription import describe_violations

__all__ = ["GaitFamily", "MemberRecord", "FamilyGait", "speed_range", "parse_speed_range",
           "check_speeds", "MAX_SPEEDS", "SPEED_TOL"]

#: a family has at most this many speeds
MAX_SPEEDS = 2000
#: two speeds closer than this (m/s) are the same
SPEED_TOL = 1e-9


# ------------------------------------------------------------------- speed grids
def speed_range(start: float, stop: float, step: float) -> np.ndarray:
    """The speeds start, start + step, ..., stop (m/s), checked.

    Parameters
    ----------
    start, stop, step : float
        m/s; 0 < start < stop, 0 < step <= stop - start, and stop - start a whole
        number of steps (within 1e-6 of one).

    Returns
    -------
    numpy.ndarray
        The speeds, rounded to 12 decimals.

    Raises
    ------
    ValueError
        Naming 'speeds' and what is wrong: not finite, not positive, empty (start =
        stop), reversed (start > stop), a step longer than the range, not a whole number
        of steps, too many.
    """
    vals = (start, stop, step)
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
               for v in vals):
        raise ValueError(f"speeds: start, stop and step must be finite numbers, got "
                         f"{start!r}:{stop!r}:{step!r}")
    if start <= 0 or stop <= 0:
        raise ValueError(f"speeds: the speeds must be positive (m/s), got {start:g} to "
                         f"{stop:g}")
    if step <= 0:
        raise ValueError(f"speeds: the step must be positive, got {step:g}")
    if start == stop:
        raise ValueError(f"speeds: the range {start:g}:{stop:g} is empty (a family needs "
                         f"start < stop)")
    if start > stop:
        raise ValueError(f"speeds: the range {start:g}:{stop:g} is reversed (start > stop)")
    n = (stop - start) / step
    if n < 1 - 1e-6:           # 0.7:0.8:1e300 was the one speed 0.7, never reaching 0.8
        raise ValueError(f"speeds: the step {step:g} is longer than the range "
                         f"{start:g}:{stop:g} (at most {stop - start:g})")
    if n > MAX_SPEEDS:
        raise ValueError(f"speeds: {start:g}:{stop:g}:{step:g} makes {n:.0f} steps, more "
                         f"than {MAX_SPEEDS}")
    if abs(n - round(n)) > 1e-6 * max(1.0, n):
        raise ValueError(f"speeds: stop - start = {stop - start:g} is not a whole number "
                         f"of steps {step:g}")
    return np.round(start + step * np.arange(round(n) + 1), 12)


def parse_speed_range(text: str) -> np.ndarray:
    """The speeds of ``'A:B:STEP'`` (:func:`speed_range`).

    Parameters
    ----------
    text : str
        Three numbers separated by colons, m/s (e.g. '0.4:1.2:0.05').

    Returns
    -------
    numpy.ndarray

    Raises
    ------
    ValueError
        Naming 'speeds': malformed text, or as :func:`speed_range`.
    """
    parts = str(text).split(":")
    try:
        if len(parts) != 3:
            raise ValueError
        a, b, s = (float(p) for p in parts)
    except ValueError:
        raise ValueError(f"speeds: expected A:B:STEP (three numbers in m/s, e.g. "
                         f"0.4:1.2:0.05), got {str(text)[:60]!r}") from None
    return speed_range(a, b, s)


def check_speeds(speeds) -> np.ndarray:
    """A sequence of speeds checked: at least two, finite, positive, strictly increasing.

    Parameters
    ----------
    speeds : sequence of float
        m/s.

    Returns
    -------
    numpy.ndarray

    Raises
    ------
    ValueError
        Naming 'speeds'.
    """
    try:
        v = np.array(speeds, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError("speeds must be a sequence of numbers (m/s)") from None
    if v.size < 2 or v.size > MAX_SPEEDS + 1:
        raise ValueError(f"speeds: a family needs 2 to {MAX_SPEEDS + 1} speeds, got {v.size}")
    if not np.all(np.isfinite(v)) or np.any(v <= 0):
        raise ValueError("speeds must be positive finite numbers (m/s)")
    if np.any(np.diff(v) <= SPEED_TOL):
        raise ValueError("speeds must be strictly increasing")
    return v


# ----------------------------------------------------------------------- results
@dataclass
class MemberRecord:
    """What continuation did at one speed of a family.

    Parameters
    ----------
    speed : float
        m/s.
    status : str
        'ok' (an exact orbit, nothing violated on the dense grid) or 'violates'
        (constraints exceeded between the nodes after the refinements).
    iterations : int
        IPOPT iterations spent reaching this speed (every substep and refinement).
    substeps : int
        Accepted solves from the previous speed (1 without halving).
    failed_steps : int
        Warm solves that failed and were halved.
    time : float
        Wall time for this member (solves, polish, checks), s.
    T, step_length : float
        s, m.
    cost : float
        The NLP's objective at its solution (integral of u'u dt / step length by the
        collocation quadrature, N^2 m s; ``Gait.cost`` recomputes it on a dense grid).
    orbit_residual : float
        The member's :meth:`Gait.orbit_residual` ``worst`` (rad, rad/s, m).
    polish_residual : float
        The polish's last residual (periodicity, z_sw(T), speed).
    polish_change : float
        Largest change of a parameter (Bezier coefficient rad, x0, T s) by the polish.
    active : list of str
        Inequality families active at the NLP solution.
    margins : dict
        The node margins the member needed (:data:`gait_opt.transcription.MARGINS`;
        found from none at each speed, as :func:`gait_opt.optimize_gait` does).
    violations : list
        [family, amount] exceeded on the dense grid (empty for a valid gait).
    branch : int
        Which branch of solutions the member lies on: 0 from the first speed, one more
        after each fold the family crossed (see ``GaitFamily.events``).
    """

    speed: float
    status: str
    iterations: int
    substeps: int
    failed_steps: int
    time: float
    T: float
    step_length: float
    cost: float
    orbit_residual: float
    polish_residual: float
    polish_change: float
    active: list
    margins: dict
    violations: list
    branch: int = 0

    def to_dict(self) -> dict:
        """The record as plain JSON types.

        Returns
        -------
        dict
        """
        return asdict(self)


@dataclass
class GaitFamily(Result):
    """Gaits at the speeds of a grid, by continuation (module docstring).

    ``success``: every requested speed has a member, each an exact orbit with nothing
    violated.

    Parameters
    ----------
    status : str
        'complete', 'ended' (the family stops before the last speed: see ``end``),
        'violates' (a member exceeds a constraint between the nodes) or 'partial' (a
        saved run not finished yet).
    message : str
        What happened, in words.
    robot : str
        The robot's name.
    speeds : list of float
        The requested speeds, m/s.
    records : list of MemberRecord
        One per member, in order of speed.
    events : list of dict
        ``speed``, ``change``, ``constraint``, ``detail``: where the set of active
        inequality families changes (``change`` 'active' or 'inactive': a kink of the
        family), and where the branch followed ends in a fold and the family continues
        on another (``change`` 'branch', ``detail`` in words, ``speed_low`` and
        ``speed_high`` the speeds between which the fold was located).
    end : dict or None
        Where and why the family ends: ``speed`` (the first speed not reached),
        ``last`` (the last reached), ``reason`` ('infeasible', 'fold', 'polish_failed'),
        ``detail``; None when it covers every speed.
    total_time : float
        Wall time of the computation, s (summed over resumed runs).
    build_time : float
        Time spent building the NLP and its solvers, s.
    options : GaitOptions
        The problem (the speed varies; left out of ``to_dict()``).
    gaits : list of Gait
        The members (left out of ``to_dict()``).
    """

    status: str
    message: str
    robot: str
    speeds: list
    records: list
    events: list = field(default_factory=list)
    end: dict | None = None
    total_time: float = 0.0
    build_time: float = 0.0
    options: GaitOptions | None = internal(default=None)
    gaits: list = internal(default_factory=list)

    SUCCESS = ("complete",)

    @property
    def model(self):
        """The robot (of the first member); ValueError for a family without one yet."""
        if not self.gaits:
            raise ValueError("family: it has no members yet (its solve stopped before the "
                             "first speed), hence no robot")
        return self.gaits[0].model

    @property
    def member_speeds(self) -> np.ndarray:
        """The speeds that have a member, m/s."""
        return np.array([r.speed for r in self.records], dtype=float)

    def __len__(self) -> int:
        return len(self.gaits)

    def gait(self, speed: float) -> Gait:
        """The member at ``speed`` (one of :attr:`member_speeds`).

        Parameters
        ----------
        speed : float
            m/s.

        Returns
        -------
        Gait

        Raises
        ------
        ValueError
            When no member has that speed.
        """
        i = self._index(speed)
        if i is None:
            raise ValueError(f"speed: no member at {speed!r} m/s (members: "
                             f"{_span(self.member_speeds)}); use gait_at for speeds between")
        return self.gaits[i]

    def _index(self, speed):
        v = self.member_speeds
        hits = np.flatnonzero(np.abs(v - float(speed)) <= SPEED_TOL)
        return int(hits[0]) if hits.size else None

    def gait_at(self, speed: float, resolve: bool = False) -> "FamilyGait":
        """A gait at any speed of the family's range (module docstring).

        Parameters
        ----------
        speed : float
            m/s, between the first and the last member.
        resolve : bool
            After the polish, solve the gait problem at ``speed`` from the polished
            interpolant (IPOPT, then the polish): the optimal gait there instead of the
            interpolated one.

        Returns
        -------
        FamilyGait

        Raises
        ------
        ValueError
            Naming 'speed' when it is not finite or outside the family.
        """
        return _gait_at(self, speed, resolve)

    def to_dict(self) -> dict:
        """The family's records in plain JSON types (what ``--json`` prints).

        Returns
        -------
        dict
            The fields, ``records`` as dicts, ``gaits`` summarised as ``members``:
            speed and orbit residual of each, plus ``speed_range`` covered and
            ``max_orbit_residual``.
        """
        d = super().to_dict()
        d["members"] = [dict(speed=r.speed, orbit_residual=r.orbit_residual, T=r.T,
                             step_length=r.step_length) for r in self.records]
        v = self.member_speeds
        d["speed_range"] = [float(v[0]), float(v[-1])] if v.size else None
        d["max_orbit_residual"] = max((r.orbit_residual for r in self.records), default=None)
        return d

    def save(self, path):
        """Write the family to one JSON file, atomically (:mod:`gait_opt.family_file`).

        Parameters
        ----------
        path : str or Path

        Returns
        -------
        Path
        """
        body = family_body(self.model.description.to_dict(), self.options, self.speeds,
                           dict(status=self.status, message=self.message, events=self.events,
                                end=self.end, total_time=self.total_time,
                                build_time=self.build_time),
                           [r.to_dict() for r in self.records], self.gaits)
        return write_family(path, body)

    @classmethod
    def load(cls, path, model=None) -> "GaitFamily":
        """Read and validate a family file (:mod:`gait_opt.family_file`).

        Parameters
        ----------
        path : str or Path
        model : BipedModel, optional
            The robot the family must be of (default: its own).

        Returns
        -------
        GaitFamily

        Raises
        ------
        GaitFileError
            Naming the file and what is wrong (every member checked as a gait file).
        """
        d = read_family_file(path, model)
        gaits = d.pop("gaits")
        records = [MemberRecord(**r) for r in d.pop("records")]
        robot = gaits[0].model.params.name if gaits else (model.params.name if model
                                                          else "")
        return cls(robot=robot, records=records, gaits=gaits, **d)


@dataclass
class FamilyGait(Result):
    """A gait of a family at a requested speed (:meth:`GaitFamily.gait_at`).

    ``success``: an exact orbit with nothing violated on the dense grid.

    Parameters
    ----------
    status : str
        'ok', 'member' (the speed is a member's: that gait), 'violates' (a constraint
        exceeded on the dense grid) or 'failed' (the polish or the re-solve failed).
    message : str
    speed : float
        m/s.
    neighbours : list of float
        The members' speeds on either side.
    interpolant_residual : float
        The polish's first residual at the interpolated parameters: max over the
        periodicity through the impact (rad, rad/s), z_sw(T) (m) and the speed
        constraint x_sw(T) - v T (m).
    interpolant_orbit_residual : float
        :meth:`Gait.orbit_residual` of the interpolant (periodicity and z_sw(T) only).
    parameter_change : float
        Largest change of a parameter by the polish (Bezier coefficients rad, x0 rad
        and rad/s, T s).
    T_change : float
        Change of T by the polish, s.
    orbit_residual : float
        Of the returned gait.
    violations : list
        [family, amount] exceeded on the dense grid.
    resolved : bool
        The gait problem was solved at ``speed`` (``resolve=True``).
    iterations : int
        IPOPT iterations of that solve (0 without).
    gait : Gait or None
        The gait (left out of ``to_dict()``).
    """

    status: str
    message: str
    speed: float
    neighbours: list
    interpolant_residual: float
    interpolant_orbit_residual: float
    parameter_change: float
    T_change: float
    orbit_residual: float
    violations: list
    resolved: bool = False
    iterations: int = 0
    gait: Gait | None = internal(default=None)

    SUCCESS = ("ok", "member")


# ---------------------------------------------------------------- continuation
def _span(v) -> str:
    return f"{v[0]:g} to {v[-1]:g} m/s" if len(v) else "none"


def _theta(gait: Gait) -> np.ndarray:
    """A gait's parameters: vec(alpha) (column by column), x0, T."""
    return np.r_[gait.alpha.ravel(order="F"), gait.x0, gait.T]


# -------------------------------------------------------------- gaits between
def _interpolant(family: GaitFamily, v: float):
    """(theta, neighbours) at speed ``v``: the cubic spline (not-a-knot; linear with two
    members) through the parameters of the members on the branch of both neighbours;
    theta None when the neighbours lie on different branches."""
    vs = family.member_speeds
    k = min(max(int(np.searchsorted(vs, v)), 1), len(vs) - 1)
    near = [float(vs[k - 1]), float(vs[k])]
    branch = [r.branch for r in family.records]
    if branch[k - 1] != branch[k]:
        return None, near
    on = [i for i, b in enumerate(branch) if b == branch[k]]
    x = vs[on]
    thetas = np.array([_theta(family.gaits[i]) for i in on])
    if len(on) > 2:
        from scipy.interpolate import CubicSpline     # (its import costs 0.2 s)
        return CubicSpline(x, thetas, axis=0)(v), near
    return np.array([np.interp(v, x, thetas[:, j]) for j in range(thetas.shape[1])]), near


def _gait_at(family: GaitFamily, speed, resolve: bool) -> FamilyGait:
    """:meth:`GaitFamily.gait_at`."""
    try:
        v = float(speed)
    except (TypeError, ValueError):
        raise ValueError(f"speed must be a number (m/s), got {speed!r}") from None
    vs = family.member_speeds
    if not math.isfinite(v):
        raise ValueError(f"speed must be finite, got {speed!r}")
    if not len(vs) or v < vs[0] - SPEED_TOL or v > vs[-1] + SPEED_TOL:
        raise ValueError(f"speed {v:g} m/s is outside the family ({_span(vs)})")
    i = family._index(v)
    if i is not None and not resolve:
        g = family.gaits[i]
        r = g.orbit_residual()["worst"]
        return FamilyGait(status="member", message=f"the member at {vs[i]:g} m/s",
                          speed=v, neighbours=[float(vs[i])] * 2, interpolant_residual=r,
                          interpolant_orbit_residual=r, parameter_change=0.0, T_change=0.0,
                          orbit_residual=r, violations=family.records[i].violations,
                          gait=g)
    model, opts_v = family.model, family.options.replace(speed=v)
    theta, near = _interpolant(family, v)
    if theta is None:
        return _between_branches(family, v, near)
    na = model.nu * (opts_v.bezier_degree + 1)
    alpha = theta[:na].reshape(model.nu, -1, order="F")
    x0, T = theta[na:na + 2], float(theta[na + 2])
    before = Gait(model, opts_v, alpha, x0, T).orbit_residual()["worst"]
    fields = dict(speed=v, neighbours=near, interpolant_orbit_residual=before)
    try:
        a_p, x0_p, T_p, hist = polish(model, opts_v, alpha, x0, T)
    except GaitOptimizationError as e:
        return FamilyGait(status="failed", message=f"the polish failed: {e}",
                          interpolant_residual=math.inf, parameter_change=math.nan,
                          T_change=math.nan, orbit_residual=math.inf, violations=[], **fields)
    change = float(np.max(np.abs(np.r_[(a_p - alpha).ravel(), x0_p - x0, T_p - T])))
    fields.update(interpolant_residual=hist[0], parameter_change=change, T_change=T_p - T)
    gait = Gait(model, opts_v, a_p, x0_p, T_p, solver_stats=dict(
        family_interpolation=dict(neighbours=near, interpolant_residual=hist[0],
                                  polish_residuals=hist, parameter_change=change)))
    what = "interpolated between the members and polished"
    iterations = 0
    if resolve:
        res = solve_once(model, opts_v, warm_start=gait)
        if res.gait is None:
            return FamilyGait(status="failed", message=f"the re-solve failed: {res.message}",
                              orbit_residual=gait.orbit_residual()["worst"], violations=[],
                              gait=gait, **fields)
        gait, iterations = res.gait, res.iterations
        what = "the optimal gait, solved from the polished interpolant"
    return _checked(gait, what + f": the interpolant missed the orbit by {hist[0]:.2e}, the "
                    f"polish changed the parameters by at most {change:.2e}", resolve,
                    iterations, fields)


def _checked(gait, what, resolved, iterations, fields) -> FamilyGait:
    """The result for a gait: 'ok' when an exact orbit with nothing violated."""
    viol = [list(x) for x in gait.violations()]
    orbit = gait.orbit_residual()["worst"]
    ok = not viol and orbit <= ORBIT_TOL
    return FamilyGait(
        status="ok" if ok else "violates", message=what + ("" if ok else (
            "; exceeded on the dense grid: " + describe_violations([tuple(x) for x in viol]))),
        orbit_residual=orbit, violations=viol, resolved=resolved, iterations=iterations,
        gait=gait, **fields)


def _between_branches(family, v, near) -> FamilyGait:
    """A speed between members of two branches (a fold between them): no interpolant;
    the gait problem solved at ``v`` from the nearer member."""
    src = near[0] if abs(v - near[0]) <= abs(v - near[1]) else near[1]
    start = family.gait(src)
    fields = dict(speed=v, neighbours=near, interpolant_residual=math.nan,
                  interpolant_orbit_residual=math.nan, parameter_change=math.nan,
                  T_change=math.nan)
    res = solve_once(family.model, family.options.replace(speed=v), warm_start=start)
    if res.gait is None:
        return FamilyGait(status="failed", message=f"between two branches of the family; "
                          f"the solve from the member at {src:g} m/s failed: {res.message}",
                          orbit_residual=math.inf, violations=[], resolved=True, **fields)
    return _checked(res.gait, f"between two branches of the family (a fold between "
                    f"{near[0]:g} and {near[1]:g} m/s): no interpolant; the optimal gait "
                    f"solved from the member at {src:g} m/s", True, res.iterations, fields)
