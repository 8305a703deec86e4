"""Speed changes on a gait family: ramps, single-step jumps and the largest jump each
controller survives (docs: theory, "Speed changes").

Every walk is full order (:func:`biped_casadi.simulation.simulate_profile`, every
validity condition checked, the run stopped at the first invalid state), on gaits of a
:class:`gait_opt.GaitFamily` (members, or the polished interpolant between them,
:func:`analysis.design.schedule.profile_gaits`), with designs made per step by
:func:`analysis.design.schedule.profile_designs`.

- :func:`profile_run` (a task): one profile of designs walked, its per-step records.
- :func:`speed_change` (a task): from v1's orbit, ``settle`` steps on v1's design, the
  switch to v2 at the next impact, ``after`` more steps on v2; it *survives* when every
  step is valid and the last error against v2's orbit is below ``tol`` (the rule of
  s*, :mod:`analysis.robustness.s_star`).
- :func:`speed_jumps`: from each start speed, the single-step changes to every member
  of the family, up and down; the largest change survived in each direction (the
  survived changes nearest v1 up to the first failure), located between the members
  by bisection on interpolated gaits.
- :func:`schedule_eigenvalues`: max|lambda| of a schedule's design at each gait, and the
  virtual constraints' eigenvalue there (check a schedule before walking it).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from biped_casadi import Design, SimulationOptions
from biped_casadi.caching import task
from biped_casadi.results import Result, json_safe
from biped_casadi.simulation.speed_profile import (CONVERGED, ProfileResult, reference_speed,
                                                   simulate_profile)

from ..design.schedule import M1Schedule, profile_designs, profile_gaits, ramp_speeds
from ..stability import poincare_eigenvalues, vc_eigenvalue

__all__ = ["SpeedChange", "SpeedJumps", "profile_run", "speed_change", "speed_jumps",
           "ramp_profile", "speed_ramp", "walk_gaits", "schedule_eigenvalues"]


# ---------------------------------------------------------------------- one profile
@task
def profile_run(designs: tuple, options: SimulationOptions, tol: float = CONVERGED
                ) -> ProfileResult:
    """One speed profile walked in full order from the first step's orbit (a task).

    Parameters
    ----------
    designs : tuple of Design
        One per step.
    options : SimulationOptions
        Validity thresholds (mu, torque limit) and integration.
    tol : float
        Convergence tolerance of the segments.

    Returns
    -------
    ProfileResult
    """
    return simulate_profile(list(designs), options=options, tol=tol)


def ramp_profile(v1: float, v2: float, dv: float, hold: int = 10, each: int = 1
                 ) -> np.ndarray:
    """The speed of every step of a ramp v1 -> v2 -> v1, then ``hold`` steps at v1.

    By ``dv`` per step, each speed ``each`` steps (:func:`speed_ramp`).

    Parameters
    ----------
    v1, v2, dv : float
        The ramp, m/s.
    hold : int
        Steps at v1 after it.
    each : int
        Steps at every speed of the ramp.

    Returns
    -------
    numpy.ndarray
        m/s, one per step.

    Raises
    ------
    ValueError
        Naming ``each`` when it is not a positive integer (and the arguments
        :func:`analysis.design.schedule.ramp_speeds` checks).
    """
    if isinstance(each, bool) or not isinstance(each, (int, np.integer)) or each < 1:
        raise ValueError(f"each must be a positive integer, got {each!r}")
    speeds = np.repeat(ramp_speeds(v1, v2, dv), each)
    return np.r_[speeds, np.full(int(hold), speeds[-1])]


def speed_ramp(family, controller: str, schedule: M1Schedule | None, options: SimulationOptions,
               v1: float, v2: float, dv: float, hold: int = 10, each: int = 1,
               gains=None) -> ProfileResult:
    """A ramp v1 -> v2 -> v1 by dv per step (each speed ``each`` steps), then ``hold``.

    Parameters
    ----------
    family : GaitFamily
        The gaits.
    controller : str
        'tv' (with ``schedule``) or 'vc'.
    schedule : M1Schedule or None
        The time-varying design over speed.
    options : SimulationOptions
        Validity thresholds.
    v1, v2, dv : float
        The ramp, m/s (:func:`analysis.design.schedule.ramp_speeds`).
    hold : int
        Steps at v1 after the ramp.
    each : int
        Steps at every speed of the ramp (1: a new gait every step; more: a staircase,
        whose segments say how many steps each switch took to converge).
    gains : Gains, optional
        Output gains.

    Returns
    -------
    ProfileResult
    """
    speeds = ramp_profile(v1, v2, dv, hold, each)
    gaits, _ = profile_gaits(family, speeds)
    return walk_gaits(gaits, speeds, controller, schedule, options, gains)


def walk_gaits(gaits, speeds, controller: str, schedule: M1Schedule | None,
               options: SimulationOptions, gains=None) -> ProfileResult:
    """A profile of given gaits walked in full order, one design per step.

    Parameters
    ----------
    gaits : sequence of Gait
        One per step (:func:`analysis.design.schedule.profile_gaits`).
    speeds : array_like
        Their speeds, m/s (what ``schedule`` is read at).
    controller, schedule, options, gains
        As :func:`speed_ramp`.

    Returns
    -------
    ProfileResult
    """
    designs = profile_designs(list(gaits), controller, schedule, gains,
                              speeds=np.asarray(speeds, dtype=float))
    return profile_run(tuple(designs), options)


# ------------------------------------------------------------------ one speed change
@dataclass
class SpeedChange(Result):
    """A single-step speed change v1 -> v2 walked in full order.

    ``success``: it survived (every step valid, converged to v2's orbit).

    Parameters
    ----------
    status : str
        'ok' (survived), 'not_converged' (every step valid, the last error not below
        ``tol``) or the first invalid state's status.
    message : str
        What went wrong.
    v1, v2, dv : float
        The speeds, m/s, and v2 - v1.
    controller : str
        'tv' or 'vc'.
    valid : bool
        Every step valid.
    switch_error : float
        The error of the first step on v2 against v2's orbit.
    final_error : float
        The last step's error (NaN if it failed).
    steps_to_converge : float
        Steps on v2, counting the switch step as 1, from which the error stays below
        ``tol`` (NaN if never).
    peak_torque, friction_margin, min_normal_force, max_impulse_ratio : float
        Over the whole walk (N m, mu minus the largest friction ratio, N, impulse
        ``|F_x| / F_z``).
    fail_step : int
        The failed step counted from the switch (0: the switch step; -1 if none).
    errors : list of float
        Every step's error against its own gait.
    """
    status: str
    message: str
    v1: float
    v2: float
    dv: float
    controller: str
    valid: bool
    switch_error: float
    final_error: float
    steps_to_converge: float
    peak_torque: float
    friction_margin: float
    min_normal_force: float
    max_impulse_ratio: float
    fail_step: int
    errors: list = field(default_factory=list)

    SUCCESS = ("ok",)


@task
def speed_change(design_v1: Design, design_v2: Design, options: SimulationOptions,
                 settle: int = 1, after: int = 10, tol: float = CONVERGED) -> SpeedChange:
    """One step change of speed: ``settle`` steps on v1 from its orbit, then v2 (a task).

    Parameters
    ----------
    design_v1, design_v2 : Design
        The designs before and after the switch, each on its gait.
    options : SimulationOptions
        Validity thresholds.
    settle : int
        Steps on v1 before the switch (from v1's orbit: settled).
    after : int
        Steps on v2 after the switch step.
    tol : float
        Convergence tolerance, rad and rad/s.

    Returns
    -------
    SpeedChange
    """
    for name, n in (("settle", settle), ("after", after)):
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {n!r}")
    if settle < 1:
        raise ValueError("settle must be at least 1 (the switch is at an impact)")
    r = simulate_profile([design_v1] * settle + [design_v2] * (after + 1), options=options,
                         tol=tol)
    e = r.errors()
    seg = r.segments[-1] if len(r.segments) > 1 else None
    valid = r.ok
    final = float(e[-1]) if valid else math.nan
    converged = valid and final < tol
    v1, v2 = reference_speed(design_v1.gait), reference_speed(design_v2.gait)
    return SpeedChange(
        status="ok" if converged else ("not_converged" if valid else r.status),
        message=r.message, v1=v1, v2=v2, dv=v2 - v1, controller=design_v2.controller,
        valid=valid, switch_error=float(e[settle]) if r.fail_step > settle or valid
        else math.nan, final_error=final,
        steps_to_converge=seg.steps_to_converge if seg is not None else math.nan,
        peak_torque=float(r.peak_torque), friction_margin=float(r.friction_margin),
        min_normal_force=float(r.min_normal_force),
        max_impulse_ratio=float(r.max_impulse_ratio),
        fail_step=-1 if valid else int(r.fail_step - settle),
        errors=[float(x) for x in e[:len(r.steps)]])


# -------------------------------------------------------------- the largest jumps
@dataclass
class SpeedJumps(Result):
    """The largest single-step speed change a controller survives, from each speed.

    ``success``: computed.  Changes are signed (m/s); 'up' is faster, 'down' slower.

    Parameters
    ----------
    status : str
        'done'.
    message : str
    controller : str
        The design's description.
    v1 : list of float
        The start speeds, m/s.
    up, down : list of float
        From each v1, the largest change survived upward (>= 0) and downward (<= 0):
        every change nearer v1 on the members' grid survived too.
    up_failed, down_failed : list of float or None
        The smallest change that failed beyond it (None: every member of the family in
        that direction survived, so the true limit is beyond the family: censored).
    resolution : list of float
        Per v1, the width of the bracket [survived, failed] left by the bisection, m/s
        (the larger of the two directions; 0 when both are censored).
    failures : list of list
        Per v1, [dv, status] of the first failure up and down.
    beyond : list of list of float
        Per v1, member changes beyond the first failure that survived again (the
        boundary is not a single threshold there).
    valid : list of list of float
        Per v1, [up, down]: the largest change with every step valid (converged or
        not) such that every change walked nearer v1 was valid too; on the changes
        walked (the members and the bisection points), so it is known to the members'
        spacing only where the bisection did not pass.
    changes : list of list of SpeedChange
        Per v1, every change walked (members and bisection points).
    settle, after : int
        Steps before and after the switch.
    """
    status: str
    message: str
    controller: str
    v1: list
    up: list
    down: list
    up_failed: list
    down_failed: list
    resolution: list
    failures: list
    beyond: list
    valid: list
    changes: list
    settle: int = 1
    after: int = 10

    SUCCESS = ("done",)

    def largest(self) -> np.ndarray:
        """The largest ``|dv|`` survived from each v1, up or down.

        Returns
        -------
        numpy.ndarray
            (n,) m/s.
        """
        return np.maximum(np.asarray(self.up, float), -np.asarray(self.down, float))


def _design_at(family, v, controller, schedule, gains, made):
    key = round(float(v), 9)
    if key not in made:
        gaits, _ = profile_gaits(family, [v])
        made[key] = profile_designs(gaits, controller, schedule, gains, speeds=[v])[0]
    return made[key]


def _direction(family, d1, targets, controller, schedule, gains, options, made, settle,
               after, refine):
    """Changes from d1 to the members ``targets`` (nearest first) until the first
    failure, the members beyond it, and the bisection between; returns (largest
    survived dv, smallest failed dv or None, [dv, status] of the failure, survived
    members beyond, every SpeedChange)."""
    v1 = reference_speed(d1.gait)
    walked, ok_dv, bad, beyond = [], 0.0, None, []
    for v2 in targets:
        c = speed_change(d1, _design_at(family, v2, controller, schedule, gains, made),
                         options, settle, after)
        walked.append(c)
        if bad is None and c.success:
            ok_dv = float(c.dv)
        elif bad is None:
            bad = c
        elif c.success:
            beyond.append(float(c.dv))
    if bad is None:
        return ok_dv, None, None, beyond, walked
    lo, hi, first = ok_dv, bad.dv, bad
    for _ in range(refine):
        mid = (lo + hi) / 2
        c = speed_change(d1, _design_at(family, v1 + mid, controller, schedule, gains, made),
                         options, settle, after)
        walked.append(c)
        if c.success:
            lo = float(c.dv)
        else:
            hi, first = float(c.dv), c
    return float(lo), float(hi), [float(hi), first.status], beyond, walked


def _valid_limit(changes) -> float:
    """The largest |dv| (signed) of the changes, nearest v1 first, that were all valid."""
    best = 0.0
    for c in sorted(changes, key=lambda c: abs(c.dv)):
        if not c.valid:
            break
        best = float(c.dv)
    return best


def speed_jumps(family, controller: str, schedule: M1Schedule | None,
                options: SimulationOptions, v1s=None, refine: int = 3, settle: int = 1,
                after: int = 10, gains=None) -> SpeedJumps:
    """The largest single-step speed change survived from each start speed.

    From each v1 (a member of ``family``) the changes to the other members, nearest
    first, are walked (:func:`speed_change`) in each direction up to the first that
    does not survive; the members beyond it are walked too (reported when one survives
    again); then ``refine`` bisection steps between the last survived change and the
    first failed one, on gaits interpolated between the members and polished.

    Parameters
    ----------
    family : GaitFamily
        The gaits (the range of the changes).
    controller : str
        'tv' (with ``schedule``) or 'vc'.
    schedule : M1Schedule or None
        The time-varying design over speed.
    options : SimulationOptions
        Validity thresholds.
    v1s : sequence of float, optional
        Start speeds (default every member).
    refine : int
        Bisection steps (each halves the bracket of the members' spacing).
    settle, after : int
        As :func:`speed_change`.
    gains : Gains, optional
        Output gains.

    Returns
    -------
    SpeedJumps
    """
    if isinstance(refine, bool) or not isinstance(refine, (int, np.integer)) or refine < 0:
        raise ValueError(f"refine must be a non-negative integer, got {refine!r}")
    members = np.sort(family.member_speeds)
    v1s = members if v1s is None else np.asarray(v1s, float).ravel()
    made = {}
    out = dict(v1=[], up=[], down=[], up_failed=[], down_failed=[], resolution=[],
               failures=[], beyond=[], valid=[], changes=[])
    for v1 in v1s:
        d1 = _design_at(family, v1, controller, schedule, gains, made)
        sides = []
        for targets in (members[members > v1 + 1e-9], members[members < v1 - 1e-9][::-1]):
            sides.append(_direction(family, d1, targets, controller, schedule, gains,
                                    options, made, settle, after, refine))
        (up, up_f, fail_u, bey_u, w_u), (dn, dn_f, fail_d, bey_d, w_d) = sides
        out["v1"].append(float(v1))
        out["up"].append(float(up))
        out["down"].append(float(dn))
        out["up_failed"].append(up_f)
        out["down_failed"].append(dn_f)
        out["resolution"].append(max(abs(up_f - up) if up_f is not None else 0.0,
                                     abs(dn_f - dn) if dn_f is not None else 0.0))
        out["failures"].append([fail_u, fail_d])
        out["beyond"].append(bey_u + bey_d)
        out["valid"].append([_valid_limit(w_u), _valid_limit(w_d)])
        out["changes"].append(w_u + w_d)
    label = "virtual constraints" if controller == "vc" else (
        Design.tv(family.gaits[0], *schedule.at(schedule.speeds[0])).label()
        if schedule.is_constant else f"M1 scheduled over {len(schedule.speeds)} speeds")
    return SpeedJumps(status="done", message="", controller=label, settle=settle,
                      after=after, **out)


# ----------------------------------------------------------------- the eigenvalues
def schedule_eigenvalues(gaits, schedule: M1Schedule | None) -> list:
    """max|lambda| of the schedule's design on each gait, beside virtual constraints'.

    Parameters
    ----------
    gaits : sequence of Gait
        The gaits (e.g. a family's members).
    schedule : M1Schedule or None
        The time-varying design over speed (None: virtual constraints only).

    Returns
    -------
    list of dict
        Per gait: ``speed``, ``M1``, ``rejoin``, ``max_abs`` and ``status`` of A^z
        (eq. 22), ``vc_eigenvalue``.
    """
    out = []
    for g in gaits:
        v = reference_speed(g)
        row = dict(speed=v, vc_eigenvalue=float(abs(vc_eigenvalue(g).eigenvalue)))
        if schedule is not None:
            M1, rejoin = schedule.at(v)
            r = poincare_eigenvalues(g, Design.tv(g, M1, rejoin))
            row.update(M1=M1.tolist(), rejoin=rejoin, max_abs=float(r.max_abs),
                       status=r.status)
        out.append(json_safe(row))
    return out
