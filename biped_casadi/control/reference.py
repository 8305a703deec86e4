"""The reference-trajectory interface the controllers, the simulator and the maps use.

A reference is one step q^d(tau), tau in [0, T], restarted at every impact and
continued smoothly past T (docs: theory §2-3).  Its symbolic form is a CasADi Function of tau
and of an internal reference state r that is integrated alongside the robot (for a
gait of :mod:`gait_opt`, r = (q_u^d, dq_u^d): the unactuated row of eq. (1) is an ODE,
so carrying it as a state keeps q_u^d exact in every discrete scheme).  A reference
given in closed form has no state (``n_state = 0``).

:class:`gait_opt.Gait` implements this interface; any other object that does can drive
:class:`~biped_casadi.control.TimeVaryingController`, the simulator and the maps of
:mod:`analysis`.
"""
from __future__ import annotations

import abc

import casadi as ca
import numpy as np

__all__ = ["Reference", "require_same_robot", "require_reference"]


def require_reference(reference, name: str = "gait"):
    """``reference`` checked to be a gait (a :class:`Reference`, or an object like one).

    Parameters
    ----------
    reference : Reference
        What the caller passed as the gait.
    name : str
        The argument's name, used in the error message.

    Returns
    -------
    Reference
        ``reference`` itself.

    Raises
    ------
    TypeError
        Naming ``name`` when it has no ``model`` and ``T`` (a path, a model, None).
    """
    if isinstance(reference, Reference) or (hasattr(reference, "T") and
                                            hasattr(getattr(reference, "model", None), "nq")):
        return reference
    raise TypeError(f"{name}: a gait is needed (gait_opt.Gait.load(path) or "
                    f"optimize_gait(model)), got {type(reference).__name__}")


def require_same_robot(model, reference) -> None:
    """Raise ``ValueError`` unless ``reference`` was made for ``model``'s robot.

    Parameters
    ----------
    model : BipedModel
        The model the caller will use.
    reference : Reference
        A reference (gait) built for some model.

    Raises
    ------
    ValueError
        When the robot parameters differ (the gait was made for another robot).
    """
    if reference.model.params != model.params:
        raise ValueError("gait: made for other robot parameters than the model "
                         f"({reference.model.params.name!r} vs {model.params.name!r})")


class Reference(abc.ABC):
    """A reference step q^d(tau) for a :class:`~biped_casadi.model.BipedModel`.

    Subclasses set ``model``, ``T`` (step duration, s), ``t_min`` (<= 0) and ``t_max``
    (>= T, the range where the numeric methods are defined), ``n_state`` and ``r0``,
    and implement :meth:`symbolic`, :meth:`evaluate` and :meth:`state`.
    """

    #: the :class:`~biped_casadi.BipedModel` the reference was made for (set by each
    #: reference, like the attributes below; the values shown are the class defaults)
    model = None
    #: step duration, s
    T: float = float("nan")
    #: earliest time the numeric methods accept, s (<= 0)
    t_min: float = 0.0
    #: latest time the numeric methods accept, s (>= T)
    t_max: float = float("nan")
    #: number of components of the reference state r (a gait: 2)
    n_state: int = 0
    #: the reference state at tau = 0 (``n_state`` numbers)
    r0: np.ndarray = np.zeros(0)

    @abc.abstractmethod
    def symbolic(self) -> ca.Function:
        """The reference as a CasADi Function.

        Returns
        -------
        casadi.Function
            ``(tau, r) -> (qd, dqd, ddqd, dr)``: q^d, its first two time derivatives
            at tau given the reference state r, and dr/dtau.
        """

    def symbolic_parametric(self):
        """The reference as a Function of parameters theta too.

        References of one kind share it (compiled code of it serves them all); by default
        theta is empty.

        Returns
        -------
        f : casadi.Function
            ``(tau, r, theta) -> (qd, dqd, ddqd, dr)``, as :meth:`symbolic`.
        theta : numpy.ndarray
            This reference's parameters.
        """
        f = self.symbolic()
        tau = ca.SX.sym("tau")
        r, th = ca.SX.sym("r", self.n_state), ca.SX.sym("theta", 0)
        return (ca.Function("reference_parametric", [tau, r, th], list(f(tau, r))),
                np.zeros(0))

    @abc.abstractmethod
    def evaluate(self, t):
        """q^d, dq^d, ddq^d at ``t`` (numeric).

        Parameters
        ----------
        t : float or array_like
            Times in [t_min, t_max].

        Returns
        -------
        tuple of numpy.ndarray
            Shapes (nq,) each for a float ``t``, (nq, N) for an array.
        """

    @abc.abstractmethod
    def state(self, t) -> np.ndarray:
        """The reference state r(t) (numeric).

        Parameters
        ----------
        t : float
            Time in [t_min, t_max], s.

        Returns
        -------
        numpy.ndarray
            Shape (n_state,).
        """

    def states(self, t) -> np.ndarray:
        """The reference state at every time of an array.

        Parameters
        ----------
        t : array_like
            N times in [t_min, t_max], s.

        Returns
        -------
        numpy.ndarray
            Shape (n_state, N).
        """
        return np.array([self.state(float(tk)) for tk in np.ravel(t)]).reshape(-1, self.n_state).T

    def state_nodes(self):
        """The nodes of the interpolant of the reference state, when it is one.

        A reference whose state r = (y, dy/dt) is the quintic Hermite interpolant of
        (y, dy/dt, d2y/dt2) on a uniform grid returns them; the export of a controller to C
        (:mod:`biped_casadi.control.export`) tabulates them.  Default: None (no state, or
        not interpolated).

        Returns
        -------
        tuple of numpy.ndarray or None
            (t, y, dy, ddy), each (N,).
        """
        return None

    # ------------------------------------------------------------ derived
    def q(self, t):
        """The reference configuration q^d(t), rad.

        Parameters
        ----------
        t : float or array_like
            Time(s) in [t_min, t_max], s (tau: time since the start of the step).

        Returns
        -------
        numpy.ndarray
            Shape (nq,) for a float ``t``, (nq, N) for N times.
        """
        return self.evaluate(t)[0]

    def dq(self, t):
        """The reference velocity dq^d/dt, rad/s.

        Parameters
        ----------
        t : float or array_like
            Time(s) in [t_min, t_max], s.

        Returns
        -------
        numpy.ndarray
            Shape (nq,) for a float ``t``, (nq, N) for N times.
        """
        return self.evaluate(t)[1]

    def ddq(self, t):
        """The reference acceleration d2q^d/dt2, rad/s^2.

        Parameters
        ----------
        t : float or array_like
            Time(s) in [t_min, t_max], s.

        Returns
        -------
        numpy.ndarray
            Shape (nq,) for a float ``t``, (nq, N) for N times.
        """
        return self.evaluate(t)[2]

    def u(self, t):
        """The reference torques u^d(t), N m: the inverse dynamics of eq. (1).

        Parameters
        ----------
        t : float or array_like
            Time(s) in [t_min, t_max], s.

        Returns
        -------
        numpy.ndarray
            Shape (nu,) for a float ``t``, (nu, N) for N times.
        """
        q, dq, ddq = self.evaluate(t)
        q2, dq2, ddq2 = (np.atleast_2d(v.T).T for v in (q, dq, ddq))
        if q2.shape[1] == 0:
            return np.zeros((self.model.nu, 0))
        u = np.array(self.model.inverse_dynamics.map(q2.shape[1])(q2, dq2, ddq2))
        return u[:, 0] if np.ndim(t) == 0 else u

    def state_at(self, t) -> np.ndarray:
        """The unactuated coordinate and its rate on the reference, (q_u^d(t), dq_u^d(t)).

        Parameters
        ----------
        t : float
            Time in [t_min, t_max], s.

        Returns
        -------
        numpy.ndarray
            Shape (2,): rad, rad/s.
        """
        q, dq, _ = self.evaluate(float(t))
        return np.array([q[0], dq[0]])
