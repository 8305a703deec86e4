"""What a running-gait file must hold to be read (:meth:`gait_opt.running.RunningGait.load`):
the fields a solve writes, each of its kind, size and range; an edited or damaged file is
refused with one line naming the field, before anything is built from it.  And the
arguments of :func:`gait_opt.running.optimize_running`, checked by name, and its solve
when IPOPT fails (the last iterate, not CasADi's exception)."""
from __future__ import annotations

import math

from biped_casadi.control.running import check_running_gait

__all__ = ["check_running_file", "running_problem", "solve_or_last_iterate"]

#: slack on the phase durations' bounds (IPOPT meets a bound to about 1e-8 s)
BOUND_SLACK = 1e-6


def _real(v) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


def check_running_file(g):
    """ValueError naming the field of a loaded running gait ``g`` that no solve writes.

    Parameters
    ----------
    g : RunningGait
        As read from a file.

    Returns
    -------
    RunningGait
        ``g``.

    Raises
    ------
    ValueError
        The robot's name not a name, a duration outside the problem's bounds, a step
        length that is not a positive number, a cost that is not a number, solver
        statistics that are not a table, states or torques not finite or of inconsistent
        shapes (:func:`biped_casadi.control.running.check_running_gait`).
    """
    if not isinstance(g.robot, str) or not g.robot.strip():
        raise ValueError(f"'robot' must be the robot's name, got {g.robot!r}")
    check_running_gait(g, name=None)
    for f, n in (("x_stance", g.options.n_stance), ("x_flight", g.options.n_flight)):
        if getattr(g, f).shape[1] != 2 * n + 1:
            raise ValueError(f"'{f}' has {getattr(g, f).shape[1]} columns; the problem's "
                             f"{n} intervals give {2 * n + 1}")
    for f, (lo, hi) in (("T_stance", g.options.stance_time_bounds),
                        ("T_flight", g.options.flight_time_bounds)):
        v = getattr(g, f)
        if not lo - BOUND_SLACK <= v <= hi + BOUND_SLACK:
            raise ValueError(f"'{f}' = {v!r} s lies outside the problem's bounds "
                             f"({lo:g}, {hi:g}) s")
    if not (_real(g.step_length) and g.step_length > 0):
        raise ValueError(f"'step_length' must be a positive number of metres, got "
                         f"{g.step_length!r}")
    if not _real(g.cost):
        raise ValueError(f"'cost' must be a finite number, got {g.cost!r}")
    if not isinstance(g.solver_stats, dict):
        raise ValueError(f"'solver_stats' must be an object, got {g.solver_stats!r}")
    return g


_GUESS = ("T_stance", "T_flight", "x_stance", "u_stance", "x_flight", "u_flight")


def running_problem(model, opts, guess, options_type):
    """The options of :func:`~gait_opt.running.optimize_running` for the robot
    (``opts`` or the defaults, lengths filled in), after its arguments are checked.

    Parameters
    ----------
    model, opts, guess
        As :func:`~gait_opt.running.optimize_running`.
    options_type : type
        :class:`~gait_opt.running.RunningOptions`.

    Returns
    -------
    RunningOptions

    Raises
    ------
    TypeError
        Naming ``model``, ``opts`` or ``guess`` when it is not of its kind.
    """
    if not all(hasattr(model, a) for a in ("nq", "nu", "description", "forward_dynamics")):
        raise TypeError(f"model must be a robot model (biped_casadi.robot), got "
                        f"{type(model).__name__}")
    if opts is not None and not isinstance(opts, options_type):
        raise TypeError(f"opts must be RunningOptions(...) or None, got {type(opts).__name__}")
    if guess is not None and not (isinstance(guess, dict) and all(k in guess for k in _GUESS)
                                  or all(hasattr(guess, k) for k in _GUESS)):
        raise TypeError(f"guess must be a RunningGait or a dict of {', '.join(_GUESS)}, got "
                        f"{type(guess).__name__}")
    return (opts or options_type()).for_model(model)


def solve_or_last_iterate(opti):
    """Solve ``opti`` (IPOPT with ``error_on_fail`` off): its stats and value function,
    those of the last iterate when IPOPT ended in failure (infeasible, an invalid number:
    CasADi raises there even so), so that the caller reports the status.

    Parameters
    ----------
    opti : casadi.Opti
        The problem, its solver set.

    Returns
    -------
    tuple
        (stats dict, value function).

    Raises
    ------
    ValueError
        Naming ``RunningOptions.ipopt`` when IPOPT never started (an option it refuses).
    """
    try:
        sol = opti.solve_limited()
        return sol.stats(), sol.value
    except RuntimeError as error:
        try:
            return opti.stats(), opti.debug.value
        except RuntimeError:
            why = (str(error).split("ipopt_interface.cpp:")[-1].partition(": ")[2]
                   or str(error))
            raise ValueError(f"RunningOptions.ipopt: IPOPT refuses the options "
                             f"({why.strip().splitlines()[0]})") from None
