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
"""
from __future__ import annotations

import ast
import re
import time
from pathlib import Path

import casadi as ca
import numpy as np

from biped_casadi.numerics import ipopt_on_one_thread, iteration_stop

from .running_file import solve_or_last_iterate

__all__ = ["stalled", "solve_running", "violated", "torque_at_limit", "STALL_FACTOR",
           "FEASIBLE", "STALL_WINDOW"]

#: the default window, iterations (``RunningOptions.stall_window``)
STALL_WINDOW = 100
#: progress the window must make: its smallest violation below this times the earlier
STALL_FACTOR = 0.5
#: a violation at most this (the constraints' own units) is feasible for the watch and
#: the report of the violated constraints
FEASIBLE = 1e-6


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


def solve_running(opti, opts, verbose, model):
    """Solve the running step's ``opti`` with IPOPT under the stall watch.

    Parameters
    ----------
    opti : casadi.Opti
        The problem, its initial values set.
    opts : RunningOptions
        Its options: ``ipopt`` over the defaults (3000 iterations, tol 1e-8, adaptive
        barrier), ``stall_window`` the watch's window (:func:`stalled`; None: no watch).
    verbose : bool
        IPOPT's iteration log.
    model : BipedModel
        The robot (the names of its joints).

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
    window = opts.stall_window
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
        g, rows = np.array(val(opti.g)).ravel(), _sources(opti)
        stats["violated"] = violated(opti, g, rows)
        names = model.joint_names
        joints = [names[int(np.argmax(np.abs(np.asarray(model.B)[:, j])))]
                  for j in range(model.nu)]
        stats["torque_at_limit"] = torque_at_limit(opti, g, rows, joints)
    return val, stats


def _labels():
    """{line number of gait_opt.running: (function name, stripped source line)}."""
    src = (Path(__file__).parent / "running.py").read_text()
    lines = src.splitlines()
    out = {}
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.FunctionDef):
            for k in range(node.lineno, (node.end_lineno or node.lineno) + 1):
                out[k] = (node.name, lines[k - 1].strip())    # inner functions come later
    return out


#: what a constraint of gait_opt.running is, from (function, a piece of its source line)
_NAMES = (("_phase stance", "bounded", "stance duration bounds", "s"),
          ("_phase stance", "", "collocation defects of stance (the dynamics)", ""),
          ("_phase flight", "bounded", "flight duration bounds", "s"),
          ("_phase flight", "", "collocation defects of flight (the dynamics)", ""),
          ("_torques", "step", "torque rate bound", "N m"),
          ("_torques", "", "torque limit |u| <= umax", "N m"),
          ("_posture", "lean", "torso lean bound", "rad"),
          ("_posture", "", "joint range (knees, hips)", "rad"),
          ("_stance_constraints", "Fz[:-1]", "normal ground force Fz >= 0 in stance", "N"),
          ("_stance_constraints", "Fz[-1]", "Fz = 0 at takeoff", "N"),
          ("_stance_constraints", "mu", "friction cone in stance", "N"),
          ("_stance_constraints", "zsw", "swing-foot clearance in stance", "m"),
          ("_cone_at_takeoff", "", "friction cone on the force's rate at takeoff", "N/s"),
          ("_cone_at_quarter_points", "", "friction cone at the quarter points", "N"),
          ("_flight_constraints", "z_st[1:]", "stance foot above the ground in flight", "m"),
          ("_flight_constraints", "z_sw[:-1]", "swing foot above the ground in flight", "m"),
          ("_flight_constraints", "z_sw[-1]", "touchdown of the swing foot", "m"),
          ("_flight_constraints", "trailing", "trailing-foot clearance at touchdown", "m"),
          ("_flight_constraints", "strike", "swing foot's strike speed", "m/s"),
          ("_edges", "qe0", "takeoff state", ""),
          ("_edges", "q_plus", "periodicity through the landing", ""),
          ("_edges", "v_other", "other foot's lift-off speed", "m/s"),
          ("_edges", "", "landing impulse (upward, in the friction cone)", "N s"),
          ("optimize_running", "Uf[:, 0]", "torques continuous through takeoff", "N m"),
          ("optimize_running", "opts.speed", "step length = speed x (stance + flight)", "m"),
          ("optimize_running", "MIN_STEP", "minimum step length", "m"))


def _name(fn, line):
    """(label, unit) of a constraint added by ``fn`` of gait_opt.running at ``line``."""
    for f, piece, label, unit in _NAMES:
        if f == fn and piece in line:
            return label, unit
    return f"{fn}: {line}", ""


def _sources(opti) -> list:
    """(function, line number, source line) of gait_opt.running that added each row of
    ``opti.g``; the function '_phase stance' or '_phase flight' for a phase's rows."""
    labels, out, phases = _labels(), [], iter(("stance", "flight"))
    phase = "?"
    for i in range(opti.ng):
        m = re.search(r"running\.py:(\d+)", opti.debug.g_describe(i))
        k = int(m.group(1)) if m else -1
        fn, line = labels.get(k, ("?", "?"))
        if fn == "_phase":              # its duration's bounds first, then its defects
            phase = next(phases, "?") if "bounded" in line else phase
            fn = f"_phase {phase}"
        out.append((fn, k, line))
    return out


def _bounds(opti, g):
    """(lbg, ubg, violation of every row) of ``opti`` at constraint values ``g``."""
    lbg = np.array(ca.evalf(opti.lbg)).ravel()
    ubg = np.array(ca.evalf(opti.ubg)).ravel()
    g = np.asarray(g, float)
    return lbg, ubg, np.maximum(lbg - g, g - ubg)


def torque_at_limit(opti, g, rows, joints, rel=1e-3) -> list:
    """The torques at (or beyond) their limit, joint by joint.

    Parameters
    ----------
    opti : casadi.Opti
        The running step's problem.
    g : array_like
        Its constraint values at an iterate.
    rows : list
        :func:`_sources` of ``opti``.
    joints : sequence of str
        The joint of every torque.
    rel : float
        At the limit: within ``rel`` times the limit of it.

    Returns
    -------
    list of dict
        ``joint``, ``count`` (points at the limit, both phases, the quarter points
        counted), ``limit`` (N m), most points first; joints with none left out.
    """
    lbg, ubg, _ = _bounds(opti, g)
    counts, start, prev, limit = {}, 0, None, None
    for i, (fn, k, line) in enumerate(rows):
        if fn != "_torques" or "umax" not in line:
            prev = None
            continue
        if k != prev:
            start, prev = i, k
        limit = float(ubg[i])
        if abs(float(g[i])) >= (1 - rel) * limit:
            j = joints[(i - start) % len(joints)]
            counts[j] = counts.get(j, 0) + 1
    out = [dict(joint=j, count=c, limit=limit) for j, c in counts.items()]
    return sorted(out, key=lambda d: -d["count"])


def violated(opti, g, rows, tol=FEASIBLE, most=3) -> list:
    """The constraint groups of the running step that ``g`` violates most.

    Parameters
    ----------
    opti : casadi.Opti
        The running step's problem (:func:`gait_opt.running.optimize_running`).
    g : array_like
        Its constraint values (``opti.g``) at an iterate.
    rows : list
        :func:`_sources` of ``opti``.
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
    v, groups = _bounds(opti, g)[2], {}
    for i in np.flatnonzero(v > tol):
        fn, _, line = rows[int(i)]
        key = _name(fn, line)
        worst, count = groups.get(key, (0.0, 0))
        groups[key] = (max(worst, float(v[i])), count + 1)
    out = [dict(name=k[0], unit=k[1], violation=w, count=c)
           for k, (w, c) in groups.items()]
    return sorted(out, key=lambda d: -d["violation"])[:most]
