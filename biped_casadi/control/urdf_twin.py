"""The Python twin of an export in URDF angles: the export's own CasADi Functions (the
ones its C is generated from) called as the C library calls them, and driven as a
controller of the model by the same loop as the library
(:class:`~biped_casadi.control.compiled.UrdfLoop`).

A law in URDF angles converts the simulator's state to the robot's angles and back
inside the law; the toolkit's law evaluated at the model's state
(:class:`~biped_casadi.control.compiled.PythonTwin`) skips both conversions, and their
round-off, grown by a closed loop over a step, parts the two runs by more than
round-off on a small or fast robot.  This twin takes the same path as the library, to
the reference's interval: the runs it drives repeat the library's to round-off.
"""
from __future__ import annotations

import math

import numpy as np

from ..numerics import FastCall
from .compiled import NumericLaw, UrdfLoop
from .export import TAU_SLACK

__all__ = ["PythonUrdfTwin"]


def _floor_div(a: float, b: float) -> float:
    """floor(a / b) as the export's C computes it (Python's float floor division)."""
    mod = math.fmod(a, b)
    div = (a - mod) / b
    if mod != 0.0 and ((b < 0.0) != (mod < 0.0)):
        div -= 1.0
    if div == 0.0:
        return 0.0
    fl = math.floor(div)
    return fl + 1.0 if div - fl > 0.5 else float(fl)


class PythonUrdfTwin(UrdfLoop, NumericLaw):
    """An export in URDF angles evaluated in Python, called as its library is.

    ``start_urdf``, ``start_leg``, ``torque_urdf`` and ``outputs_urdf`` evaluate the
    export's ``biped_front``, ``biped_start`` and ``biped_law`` with the C's checks,
    return codes and reference interval; as a controller of the model it is the library's
    loop (:class:`~biped_casadi.control.compiled.UrdfLoop`).

    Parameters
    ----------
    exported : TimeVaryingController or VirtualConstraintController
        The exported controller.
    law : ExportedLaw
        Its export in URDF angles (``angles='urdf'``).
    """

    name = "python-urdf"

    def __init__(self, exported, law):
        if law.angles != "urdf":
            raise ValueError(f"law: an export in URDF angles, got angles={law.angles!r}")
        super().__init__(exported)
        self.n_par += 1
        self.law_info = law
        self._law, self._start_fn = FastCall(law.law), FastCall(law.start)
        self._front = FastCall(law.front)
        self._urdf_loop(law.urdf, law.motor_side)

    @property
    def cache_key(self):
        """What the simulator of this law depends on: the exported controller and side."""
        return ("python-urdf-twin", self.exported.cache_key, self.motor_side)

    def start_leg(self, stance: int, x, dx) -> tuple:
        """``biped_step_start_leg``: (return code, state), the stance leg given (0 or 1).

        Parameters
        ----------
        stance : int
            0 for the map's leg 1, 1 for leg 2.
        x, dx : numpy.ndarray
            Pitch and URDF joint angles, and rates.

        Returns
        -------
        tuple
        """
        if stance not in (0, 1):
            return 2, np.full(self.n_par, np.nan)
        p, go = self._start_fn(x, dx, float(stance))
        p = p.ravel()
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(dx))):
            return 3, p
        if not go[0, 0] > 0.0:
            return 2, p
        return (0 if np.all(np.isfinite(p)) else 3), p

    def start_urdf(self, x, dx) -> tuple:
        """``biped_step_start``: (return code, state), the stance leg the foot in front.

        Parameters
        ----------
        x, dx : numpy.ndarray
            Pitch and URDF joint angles, and rates.

        Returns
        -------
        tuple
        """
        ahead = float(self._front(x)[0][0, 0])
        if not math.isfinite(ahead):
            return 3, np.full(self.n_par, np.nan)
        if ahead == 0.0:
            return 2, np.full(self.n_par, np.nan)
        return self.start_leg(0 if ahead < 0.0 else 1, x, dx)

    def _node(self, tau: float) -> np.ndarray:
        t = self.law_info.table
        if t is None:
            return np.zeros(0)
        k = _floor_div(tau - t["t0"], t["h"]) - float(t["offset"])
        last = t["t"].size - 2
        i = 0 if k < 0.0 else (last if k > last else int(k))
        return np.array([t["t"][i], t["h"], t["y"][i], t["dy"][i], t["ddy"][i],
                         t["y"][i + 1], t["dy"][i + 1], t["ddy"][i + 1]])

    def _evaluate(self, tau, x, dx, state):
        li = self.law_info
        if not (state[0] in (0.0, 1.0) and 0.0 <= tau <= li.tau_max + TAU_SLACK):
            return 2, None
        u, y, dy, den, inr = self._law(x, dx, tau, state, self._node(tau))
        den = float(den[0, 0])
        if not inr[0, 0] > 0.0:
            return 2, None
        if not (math.isfinite(den) and np.all(np.isfinite(u))):
            return 3, (u.ravel(), y.ravel(), dy.ravel(), den)
        rc = 0 if den * li.den_sign > li.singular_fraction * li.den_scale else 1
        return rc, (u.ravel(), y.ravel(), dy.ravel(), den)

    def torque_urdf(self, tau, x, dx, state) -> tuple:
        """``biped_torque``: (return code, torque per URDF joint; NaN out of range).

        Parameters
        ----------
        tau : float
            Time since the step started, s.
        x, dx, state : numpy.ndarray
            Pitch and URDF joint angles, rates, the state of a step start.

        Returns
        -------
        tuple
        """
        rc, out = self._evaluate(tau, x, dx, state)
        return rc, (np.full(self.nu, np.nan) if out is None else out[0])

    def outputs_urdf(self, tau, x, dx, state) -> tuple:
        """``biped_outputs``: (return code, y, dy, den).

        Parameters
        ----------
        tau : float
            Time since the step started, s.
        x, dx, state : numpy.ndarray
            As :meth:`torque_urdf`.

        Returns
        -------
        tuple
        """
        rc, out = self._evaluate(tau, x, dx, state)
        if out is None:
            nan = np.full(self.nu, np.nan)
            return rc, nan, nan, np.nan
        return (rc,) + out[1:]

    def describe(self) -> dict:
        """What defines the law, as a JSON-ready dict.

        Returns
        -------
        dict
            ``controller`` ('python-urdf'), ``exported`` (the controller's
            ``describe()``), ``motor_side``.
        """
        return dict(controller="python-urdf", exported=self.exported.describe(),
                    motor_side=self.motor_side)
