"""What a running-gait file must hold to be read (:meth:`gait_opt.running.RunningGait.load`):
the fields a solve writes, each of its kind, size and range; an edited or damaged file is
refused with one line naming the field, before anything is built from it."""
from __future__ import annotations

import math

from biped_casadi.control.running import check_running_gait

__all__ = ["check_running_file"]

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
