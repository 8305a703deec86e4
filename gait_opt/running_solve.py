"""IPOPT on the running step's NLP (:func:`gait_opt.running.optimize_running`): a watch
on the constraint violation that ends a search no longer approaching feasibility, and,
when a solve fails, the constraints its last iterate violates most.

Why a watch.  A speed the robot cannot run at (RABBIT beyond about 3 m/s under its
150 N m limit, docs: howto/running.md) left IPOPT searching its 3000 iterations (at
4 m/s 142 to 207 s on two shared cores) before the one line "did not converge".  The converging solves of the
default grid take 22 to 77 iterations (RABBIT, 0.8 to 3 m/s); the watch reads the
largest constraint violation at every iterate and stops the search (IPOPT's
'User_Requested_Stop', reported as a stall) when, over the last ``window`` iterations,
its smallest value came no lower than :data:`STALL_FACTOR` times the smallest before
them, and no iterate so far came within :data:`FEASIBLE`.  It cannot act before IPOPT's iteration
``window`` (it needs the window's iterates and one before them), so a solve that
converges in fewer iterations is the same with or without it, bit for bit.

The report of a failure names the violated rows by the labels they were added under
(:class:`LabelledConstraints`, the running step's transcription adds every constraint
through it).
"""
from __future__ import annotations

import time

import casadi as ca
import numpy as np

from biped_casadi.numerics import ipopt_on_one_thread, iteration_stop

from .running_file import solve_or_last_iterate

__all__ = ["stalled", "solve_running", "violated", "torque_at_limit", "torque_rows",
           "torque_peaks", "within_path_limits", "LabelledConstraints", "STALL_FACTOR",
           "FEASIBLE", "STALL_WINDOW", "TORQUE_LIMIT", "MAX_TIGHTENINGS", "TORQUE_TOL"]

#: the default window, iterations (``RunningOptions.stall_window``)
STALL_WINDOW = 100
#: progress the window must make: its smallest violation below this times the earlier
STALL_FACTOR = 0.5
#: a violation at most this (the constraints' own units) is feasible for the watch and
#: the report of the violated constraints
FEASIBLE = 1e-6
#: the label of the rows |u| <= umax (:func:`torque_at_limit` reads them)
TORQUE_LIMIT = "torque limit |u| <= umax"
#: re-solves allowed for a torque beyond its limit or a foot below its bound between the
#: points (:func:`within_path_limits`)
MAX_TIGHTENINGS = 3
#: a torque at most this above its limit, N m, is within it (the tolerance of
#: ``RunningReport.violations``)
TORQUE_TOL = 1e-7


class LabelledConstraints:
    """The constraints of an ``Opti``, each added under the label its failure report shows.

    Parameters
    ----------
    opti : casadi.Opti
        The problem the constraints are added to (``groups`` covers every row of its
        ``g`` when all of them come through :meth:`add`).

    Attributes
    ----------
    groups : list of tuple
        (label, unit, start, stop) of every :meth:`add`, in order: its rows
        ``start:stop`` of ``opti.g``.
    """

    def __init__(self, opti):
        self.opti, self.groups = opti, []

    def add(self, label, unit, constraint):
        """``opti.subject_to(constraint)``, its rows of ``opti.g`` kept under ``label``.

        Parameters
        ----------
        label : str
            What the rows are, as a failure shows it (:func:`violated`).
        unit : str
            Their unit ('' for none, or mixed).
        constraint : casadi.MX
            The constraint, as ``opti.subject_to`` takes it.
        """
        start = self.opti.ng
        self.opti.subject_to(constraint)
        self.groups.append((label, unit, start, self.opti.ng))


def stalled(violations, window, factor=STALL_FACTOR, tol=FEASIBLE) -> bool:
    """Whether a search's constraint violation has stalled.

    Parameters
    ----------
    violations : sequence of float
        The largest constraint violation at every iterate so far, first to last.
    window : int or None
        Iterations the violation has to make progress in; None: never stalled.
    factor : float
        The progress asked: the smallest of the last ``window`` below ``factor`` times
        the smallest before them.
    tol : float
        A smallest violation of the window at most this is feasible, never stalled.

    Returns
    -------
    bool
        True when more than ``window`` iterates are known, the last ``window`` made less
        than that progress and no iterate so far came within ``tol`` (a search that met
        the constraints once and left them to lower its cost is not stalled: ODRI's
        Bolt at 1 m/s is feasible to 1.3e-7 at iteration 12, 2.7e-4 a hundred
        iterations later, and converges at iteration 197).
    """
    if window is None or len(violations) <= window:
        return False
    recent, before = min(violations[-window:]), min(violations[:-window])
    return before > tol and recent > tol and recent > factor * before


class _Watch:
    """The largest violation of every iterate, and whether the search has
    :func:`stalled` (IPOPT's iteration callback stops it then)."""

    def __init__(self, opti, window):
        self.window = window
        self.lbg = np.array(ca.evalf(opti.lbg)).ravel()
        self.ubg = np.array(ca.evalf(opti.ubg)).ravel()
        self.violations, self.stopped = [], False
        self.callback = iteration_stop("running_watch", opti.nx, opti.ng, self.see)

    def see(self, g) -> bool:
        """Record an iterate's constraint values ``g``; True: stop."""
        v = np.maximum(self.lbg - g, g - self.ubg)
        self.violations.append(float(max(0.0, np.max(v))) if v.size else 0.0)
        self.stopped = stalled(self.violations, self.window)
        return self.stopped


def solve_running(con, opts, verbose, model, watch=True):
    """Solve the running step's problem with IPOPT under the stall watch.

    Parameters
    ----------
    con : LabelledConstraints
        The problem (``con.opti``, its initial values set) and its labelled rows.
    opts : RunningOptions
        Its options: ``ipopt`` over the defaults (3000 iterations, tol 1e-8, adaptive
        barrier), ``stall_window`` the watch's window (:func:`stalled`; None: no watch).
    verbose : bool
        IPOPT's iteration log.
    model : BipedModel
        The robot (the names of its joints).
    watch : bool
        False: no watch whatever ``stall_window`` (a re-solve of
        :func:`within_path_limits`, from a converged step: the watch, reading its first
        iterate's small violation as the best, stopped ODRI's Bolt's re-solve after 108
        iterations; without it, 440).

    Returns
    -------
    tuple
        (value function, solver_stats), the last iterate's when IPOPT failed
        (:func:`gait_opt.running_file.solve_or_last_iterate`); ``solver_stats`` has
        ``success``, ``return_status`` ('Stalled' when the watch stopped the search),
        ``iterations``, ``wall_s`` and, when it failed, ``violated`` (:func:`violated`)
        and ``torque_at_limit`` (:func:`torque_at_limit`) at the last iterate.
    """
    ipopt = {"print_level": 5 if verbose else 0, "max_iter": 3000, "tol": 1e-8,
             "mu_strategy": "adaptive", "sb": "yes", **opts.ipopt}
    opti, window = con.opti, opts.stall_window if watch else None
    watch = None if window is None else _Watch(opti, window)
    extra = {} if watch is None else {"iteration_callback": watch.callback}
    ipopt_on_one_thread()
    opti.solver("ipopt", {"expand": True, "print_time": False, "error_on_fail": False,
                          "show_eval_warnings": False, **extra}, ipopt)
    t0 = time.perf_counter()
    st, val = solve_or_last_iterate(opti)
    stats = {"success": bool(st.get("success")), "return_status": st.get("return_status"),
             "iterations": int(st.get("iter_count", -1)), "wall_s": time.perf_counter() - t0}
    if watch is not None and watch.stopped and not stats["success"]:
        stats["return_status"] = "Stalled"
        stats["stall_window"] = window
    if not stats["success"]:
        g = np.array(val(opti.g)).ravel()
        stats["violated"] = violated(opti, g, con.groups)
        names = model.joint_names
        joints = [names[int(np.argmax(np.abs(np.asarray(model.B)[:, j])))]
                  for j in range(model.nu)]
        stats["torque_at_limit"] = torque_at_limit(opti, g, con.groups, joints)
    return val, stats


def _bounds(opti, g):
    """(lbg, ubg, violation of every row) of ``opti`` at constraint values ``g``."""
    lbg = np.array(ca.evalf(opti.lbg)).ravel()
    ubg = np.array(ca.evalf(opti.ubg)).ravel()
    g = np.asarray(g, float)
    return lbg, ubg, np.maximum(lbg - g, g - ubg)


def torque_rows(con, opts, U, umax, T, n):
    """A phase's torque rows: |u| <= umax at every point and at the quarter points of
    every interval (where the quadratic torque of Hermite-Simpson overshoots its three
    values most), and, with ``torque_rate_max``, a bound on the torque's rate between
    neighbouring points.

    Parameters
    ----------
    con : LabelledConstraints
        The running step's problem (the rows |u| <= umax labelled :data:`TORQUE_LIMIT`).
    opts : RunningOptions
        Its options (``torque_rate_max``).
    U : casadi.MX
        (nu, 2 n + 1) the phase's torques, point after point.
    umax : float or tuple of float
        The bound, N m: one number, or one per torque u1 .. u_nu
        (:meth:`~gait_opt.running.RunningOptions.limit`).
    T : casadi.MX
        The phase's duration, s.
    n : int
        Its Hermite-Simpson intervals.
    """
    def bounded(u):                            # ca.vec: point after point
        lim = umax if np.ndim(umax) == 0 else ca.DM(np.tile(umax, u.shape[1]))
        return con.opti.bounded(-lim, ca.vec(u), lim)
    con.add(TORQUE_LIMIT, "N m", bounded(U))
    u0, um, u1 = U[:, 0:-1:2], U[:, 1::2], U[:, 2::2]
    for a, b, c in ((0.375, 0.75, -0.125), (-0.125, 0.75, 0.375)):
        con.add(TORQUE_LIMIT, "N m", bounded(a * u0 + b * um + c * u1))
    if opts.torque_rate_max is not None:
        du = ca.vec(U[:, 1:] - U[:, :-1])
        step = opts.torque_rate_max * T / (2 * n)
        con.add("torque rate bound", "N m", du <= step)
        con.add("torque rate bound", "N m", du >= -step)


def torque_at_limit(opti, g, groups, joints, rel=1e-3) -> list:
    """The torques at (or beyond) their limit, joint by joint.

    Parameters
    ----------
    opti : casadi.Opti
        The running step's problem.
    g : array_like
        Its constraint values at an iterate.
    groups : list
        ``LabelledConstraints.groups`` of ``opti``: the groups labelled
        :data:`TORQUE_LIMIT` are read, each one's rows the torques point after point.
    joints : sequence of str
        The joint of every torque.
    rel : float
        At the limit: within ``rel`` times the limit of it.

    Returns
    -------
    list of dict
        ``joint``, ``count`` (points at the limit, both phases, the quarter points
        counted), ``limit`` (N m, the joint's), most points first; joints with none left
        out.
    """
    ubg = _bounds(opti, g)[1]
    counts, limits = {}, {}
    for label, _, start, stop in groups:
        if label != TORQUE_LIMIT:
            continue
        for i in range(start, stop):
            limit = float(ubg[i])
            if abs(float(g[i])) >= (1 - rel) * limit:
                j = joints[(i - start) % len(joints)]
                counts[j], limits[j] = counts.get(j, 0) + 1, limit
    out = [dict(joint=j, count=c, limit=limits[j]) for j, c in counts.items()]
    return sorted(out, key=lambda d: -d["count"])


def violated(opti, g, groups, tol=FEASIBLE, most=3) -> list:
    """The constraint groups of the running step that ``g`` violates most.

    Parameters
    ----------
    opti : casadi.Opti
        The running step's problem (:func:`gait_opt.running.optimize_running`).
    g : array_like
        Its constraint values (``opti.g``) at an iterate.
    groups : list
        ``LabelledConstraints.groups`` of ``opti``: (label, unit, start, stop).
    tol : float
        Violations at most this are not counted.
    most : int or None
        Groups given at most (None: all).

    Returns
    -------
    list of dict
        ``name``, ``unit``, ``violation`` (the largest), ``count`` (entries violated),
        largest violation first.
    """
    v, named = _bounds(opti, g)[2], {}
    for label, unit, start, stop in groups:
        bad = v[start:stop][v[start:stop] > tol]
        if bad.size:
            worst, count = named.get((label, unit), (0.0, 0))
            named[label, unit] = (max(worst, float(np.max(bad))), count + bad.size)
    out = [dict(name=k[0], unit=k[1], violation=w, count=c)
           for k, (w, c) in named.items()]
    return sorted(out, key=lambda d: -d["violation"])[:most]


def torque_peaks(U) -> np.ndarray:
    """The largest ``|u_i|`` of each torque on a phase's Hermite-Simpson interpolant,
    exactly: on every interval the quadratic through its three values
    (:func:`gait_opt.running.hermite_simpson`) peaks at an end or at its vertex.

    Parameters
    ----------
    U : array_like
        (nu, 2 n + 1) the phase's torques at the interval ends and midpoints, N m.

    Returns
    -------
    numpy.ndarray
        (nu,) the peak of each torque over the phase, N m.
    """
    U = np.asarray(U, dtype=float)
    u0, um, u1 = U[:, 0:-1:2], U[:, 1::2], U[:, 2::2]
    a, b = 2 * u0 - 4 * um + 2 * u1, -3 * u0 + 4 * um - u1      # u0 + b s + a s^2
    s = np.divide(-b, 2 * a, out=np.zeros_like(a), where=a != 0)
    inside = (s > 0) & (s < 1)
    vertex = np.where(inside, u0 + b * s + a * s * s, 0.0)
    return np.max(np.abs(np.concatenate([u0, u1, vertex], axis=1)), axis=1)


def within_path_limits(solve, limit, dips=None, rounds=MAX_TIGHTENINGS, tol=TORQUE_TOL):
    """A running step whose torques and feet keep their bounds between the points too.

    The NLP bounds each torque at the points and the quarter points of every interval,
    and the feet at the points; where the quadratic torque peaks above a limit between
    them (:func:`torque_peaks`), or a foot dips below its bound (``dips``), the walking
    optimiser's remedy (:func:`gait_opt.optimize.optimize_gait`): that joint's bound is
    lowered by its excess, that foot is held above its bound between the points too
    (:func:`gait_opt.running_clearance.clearance_rows`), and the problem is solved
    again from the step found, both in one re-solve, at most ``rounds`` times.  A step
    within its bounds is returned as solved, so a step whose bounds do not bind between
    the points is the same bit for bit.

    Parameters
    ----------
    solve : callable
        ``solve(guess, umax, points)``: the step from a guess (None: the built-in one;
        or a previous step) under the bound ``umax`` (a number or one per torque), the
        feet also bounded at ``points`` (a tuple of ``dips``' dicts, empty at first), a
        :class:`~gait_opt.running.RunningGait`.
    limit : float or tuple of float
        The torque limit, N m (:meth:`~gait_opt.running.RunningOptions.limit`).
    dips : callable, optional
        ``dips(gait)``: the feet's dips below their bounds between the points, a list
        of dicts (:func:`gait_opt.running_clearance.foot_dips`); None: torques only.
    rounds : int
        Re-solves allowed.
    tol : float
        A torque excess at most this, N m, is within the limit (``dips`` has its own).

    Returns
    -------
    RunningGait
        The last step solved (the one before, when a re-solve failed).  After a
        re-solve, ``solver_stats['tightenings']`` lists each one's ``bound`` (N m, per
        torque), ``excess`` (the torques' peaks above the limit that lowered it, N m),
        ``dips`` (the feet's dips bounded from then on), ``iterations`` and ``wall_s``
        (and ``failed``, IPOPT's status, if it failed); ``iterations`` and ``wall_s``
        are then totals over all solves.
    """
    gait = solve(None, limit, ())
    target = np.broadcast_to(np.asarray(limit, dtype=float), (gait.u_stance.shape[0],))
    bound, points, passes, first = target.copy(), (), [], dict(gait.solver_stats)
    for _ in range(rounds):
        if not gait.success:
            break
        excess = np.maximum(torque_peaks(gait.u_stance), torque_peaks(gait.u_flight)) - target
        low = [] if dips is None else dips(gait)
        if np.all(excess <= tol) and not low:
            break
        bound = bound - np.where(excess > tol, excess, 0.0)
        points = points + tuple(low)
        new = solve(gait, tuple(float(v) for v in bound), points)
        passes.append(dict(bound=bound.tolist(), excess=excess.tolist(), dips=low,
                           iterations=new.solver_stats["iterations"],
                           wall_s=new.solver_stats["wall_s"]))
        if not new.success:
            passes[-1]["failed"] = new.solver_stats["return_status"]
            break
        gait = new
    if passes:
        gait.solver_stats.update(
            tightenings=passes,
            iterations=first["iterations"] + sum(p["iterations"] for p in passes),
            wall_s=first["wall_s"] + sum(p["wall_s"] for p in passes))
    return gait
