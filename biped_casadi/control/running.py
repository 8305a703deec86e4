"""A controller that tracks a collocated running gait: stance and flight, each with its
own reference, the time t restarting at 0 when the phase begins.

Reference.  Each phase of the gait (:class:`gait_opt.running.RunningGait`, or any object
with its fields ``T_stance``, ``T_flight``, ``x_stance``, ``u_stance``, ``x_flight``,
``u_flight``) was transcribed by Hermite-Simpson collocation: states and torques at the
ends and midpoints of ``n`` intervals.  :class:`PhaseReference` is its interpolant as a
CasADi expression of t, the one the transcription implies (Kelly 2017, eq. 4.10): on
each interval every state component is the cubic whose derivative is the quadratic
through the dynamics f(x, u) at the interval's ends and midpoint, and the torque the
quadratic through its three values.  So

- q^d(t): the cubic of the position components, through the nodes;
- dq^d(t): the cubic of the velocity components (the state's own interpolant, not the
  derivative of q^d; the two agree at the nodes and differ by the transcription's error
  between them);
- ddq^d(t): the derivative of dq^d, the quadratic through the accelerations
  ``forward_dynamics`` (stance) or ``flight_dynamics`` (flight) at the nodes;
- u^d(t): the quadratic through the collocated torques (the feedforward).

At the interval ends the interpolant is the collocated state exactly; at the midpoints
it is the collocated midpoint state up to the midpoint condition's residual (IPOPT's
tolerance).  Beyond the phase's end (a phase that lasts longer than the reference) the
last interval's polynomials continue (smooth: C^infinity past the end); before 0, the
first interval's.

Law.  The controlled output is v = M q, M = [M1, I] (M1 a column on the unactuated
angle q1; M1 = 0: plain joint tracking), with the same q in flight (the first nq
extended coordinates; the base is not an output).  Two laws:

- ``"pd"``: u = u^d(t) + Kp (v^d(t) - v) + Kd (dv^d(t) - dv), v^d = M q^d; Kp in N m/rad,
  Kd in N m s/rad;
- ``"computed_torque"``: the torque that gives dd v = M ddq^d(t) + Kp (v^d - v) + Kd
  (dv^d - dv) through the phase's dynamics (stance: D ddq + H = B u; flight: De ddqe +
  He = Be u), u = (M D^-1 B)^-1 (a + M D^-1 H); Kp in 1/s^2, Kd in 1/s.  Singular where
  M D^-1 B is (never for M1 = 0: B' D^-1 B is positive definite).

Clock.  The laws take the time t of their reference.  In stance it is the time since
landing.  In flight the closed loop gives either the time since the takeoff
('takeoff', the reference restarting there) or the stance's clock continued, the time
since landing less T_stance ('stride'; before 0 when the stance ended early, where the
first interval's polynomials continue): the two differ when the takeoff is earlier or
later than the reference's, and only the second keeps the law's torque continuous
through it where the gait's is (:data:`FLIGHT_CLOCKS`).

Torques are saturated at the model's limit, as the walking simulator does with
``SimulationOptions(saturate=True)``, when ``saturate`` is set; otherwise the closed
loop that uses this controller treats ``|u|`` > limit as a violation
(:mod:`analysis.stability.running_cycle`).

This module is in the bottom layer: it imports nothing from :mod:`gait_opt`.
"""
from __future__ import annotations

import copy
import math

import casadi as ca
import numpy as np

from ..model import flight_model
from .output_law import check_M1_range
from .saturation import clip_torques

__all__ = ["PhaseReference", "RunningController", "LAWS", "FLIGHT_CLOCKS",
           "phase_derivatives", "check_running_gait"]

#: the tracking laws (module docstring)
LAWS = ("pd", "computed_torque")

#: the flight reference's clock, which the closed loop gives the flight law (module
#: docstring): 'takeoff', the time since the takeoff; 'stride', the stance's clock
#: continued, the time since landing less T_stance
FLIGHT_CLOCKS = ("takeoff", "stride")

_FIELDS = ("T_stance", "T_flight", "x_stance", "u_stance", "x_flight", "u_flight")


def phase_derivatives(model, phase: str, X, U) -> np.ndarray:
    """f(x, u) of a phase at its collocation points (the dynamics the transcription used).

    Parameters
    ----------
    model : BipedModel
        The robot.
    phase : str
        'stance' (x = (q, dq)) or 'flight' (x = (qe, dqe)).
    X, U : array_like
        (2 n, N) states and (nu, N) torques.

    Returns
    -------
    numpy.ndarray
        (2 n, N) time derivatives.
    """
    X, U = np.asarray(X, float), np.asarray(U, float)
    if phase == "stance":
        n, dyn = model.nq, model.forward_dynamics
    elif phase == "flight":
        n, dyn = flight_model(model).ne, flight_model(model).flight_dynamics
    else:
        raise ValueError(f"phase must be 'stance' or 'flight', got {phase!r}")
    N = X.shape[1]
    acc = np.array(dyn.map(N)(X[:n], X[n:], U)).reshape(n, N)
    return np.vstack([X[n:], acc])


class PhaseReference:
    """The Hermite-Simpson interpolant of one collocated phase as a CasADi Function of t.

    Parameters
    ----------
    name : str
        The phase's name (the Function is called ``<name>_reference``).
    duration : float
        The phase's duration T, s; the points sit at T k / (2 n), k = 0 .. 2 n.
    X : array_like
        (2 ne, 2 n + 1) collocated states (positions, then velocities).
    F : array_like
        (2 ne, 2 n + 1) their time derivatives f(X, U).
    U : array_like
        (nu, 2 n + 1) collocated torques, N m.
    nq : int
        How many leading coordinates are returned (the stance coordinates q; a flight
        phase's base coordinates follow them and are dropped).

    Attributes
    ----------
    function : casadi.Function
        ``ref(t) -> (q^d, dq^d, ddq^d, u^d)``, (nq,), (nq,), (nq,), (nu,).
    t_nodes : numpy.ndarray
        (2 n + 1,) the points' times, s.
    """

    def __init__(self, name: str, duration: float, X, F, U, nq: int):
        X, F, U = (np.asarray(a, float) for a in (X, F, U))
        if X.ndim != 2 or X.shape != F.shape or X.shape[1] != U.shape[1] \
                or X.shape[1] % 2 != 1 or X.shape[1] < 3 or X.shape[0] % 2:
            raise ValueError(f"{name}: states, derivatives and torques of 2 n + 1 points "
                             f"are needed, got {X.shape}, {F.shape}, {U.shape}")
        if not (math.isfinite(duration) and duration > 0):
            raise ValueError(f"{name}: the duration must be positive, got {duration!r}")
        self.name, self.duration, self.nq = name, float(duration), int(nq)
        ne = X.shape[0] // 2
        n = (X.shape[1] - 1) // 2
        self.n_intervals, self.ne = n, ne
        self.t_nodes = np.linspace(0.0, self.duration, 2 * n + 1)
        h = self.duration / n
        rows = np.r_[0:nq, ne:ne + nq]                      # q then dq of the stance coordinates
        # per interval, the polynomials' coefficients in tau = t - t_k (powers 0..3):
        # x = X0 + f0 tau + (-3 f0 + 4 fm - f1) tau^2 / (2 h) + (2 f0 - 4 fm + 2 f1) tau^3 / (3 h^2)
        # u = u0 + (-3 u0 + 4 um - u1) tau / h + (2 u0 - 4 um + 2 u1) tau^2 / h^2
        coeffs = []
        for k in range(n):
            i = 2 * k
            x0, f0, fm, f1 = X[rows, i], F[rows, i], F[rows, i + 1], F[rows, i + 2]
            u0, um, u1 = U[:, i], U[:, i + 1], U[:, i + 2]
            cx = np.stack([x0, f0, (-3 * f0 + 4 * fm - f1) / (2 * h),
                           (2 * f0 - 4 * fm + 2 * f1) / (3 * h * h)], axis=1)
            cu = np.stack([u0, (-3 * u0 + 4 * um - u1) / h, (2 * u0 - 4 * um + 2 * u1) / h ** 2],
                          axis=1)
            coeffs.append(np.r_[self.t_nodes[i], cx.ravel(), cu.ravel()])
        t = ca.SX.sym("t")
        # the interval of t: the first whose end is past t (the last beyond the end, the
        # first before 0); a chain of selections of constants, the polynomial once
        C = ca.DM(coeffs[-1])
        for k in range(n - 2, -1, -1):
            C = ca.if_else(t < self.t_nodes[2 * k + 2], ca.DM(coeffs[k]), C)
        tau = t - C[0]
        nx = 2 * nq
        cx = ca.reshape(C[1:1 + 4 * nx], 4, nx).T          # (nx, 4), row-major above
        cu = ca.reshape(C[1 + 4 * nx:], 3, U.shape[0]).T
        x = cx[:, 0] + tau * (cx[:, 1] + tau * (cx[:, 2] + tau * cx[:, 3]))
        dx = cx[:, 1] + tau * (2 * cx[:, 2] + tau * 3 * cx[:, 3])
        u = cu[:, 0] + tau * (cu[:, 1] + tau * cu[:, 2])
        out = ca.vertcat(x[:nq], x[nq:], dx[nq:], u)
        nu = U.shape[0]
        self.nu = nu
        self.function = ca.Function(f"{name}_reference", [t],
                                    [out[:nq], out[nq:2 * nq], out[2 * nq:3 * nq], out[3 * nq:]],
                                    ["t"], ["q", "dq", "ddq", "u"])

    def __call__(self, t):
        """(q^d, dq^d, ddq^d, u^d) at t (a float, or a CasADi symbol), as the Function's
        outputs."""
        return self.function(t)

    def sample(self, t) -> tuple:
        """The reference at an array of times, as numpy columns.

        Parameters
        ----------
        t : array_like
            Times from the phase's start, s.

        Returns
        -------
        tuple of numpy.ndarray
            (q, dq, ddq, u), each (rows, len(t)).
        """
        t = np.atleast_1d(np.asarray(t, float))
        out = self.function.map(t.size)(t[None, :])
        return tuple(np.array(v) for v in out)


def _number_array(name, value) -> np.ndarray:
    """``value`` as floats, or a ValueError naming ``name`` (text, ragged lists)."""
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numbers, got {value!r}") from None


def _torque_limit(model, torque_limit, saturate: bool):
    """The controller's torque limit (:class:`RunningController`): a float, or a tuple of
    nu floats (one per torque); a ValueError naming ``torque_limit`` where it is none."""
    lim = _number_array("torque_limit", model.description.torque_bound
                        if torque_limit is None else torque_limit)
    if lim.ndim > 1 or (lim.ndim == 1 and lim.size != model.nu):
        raise ValueError(f"torque_limit must be one number or {model.nu}, one per torque, "
                         f"got {torque_limit!r}")
    unusable = saturate and not np.all(np.isfinite(lim))    # inf: a robot without one
    if not np.all(lim > 0) or (unusable and torque_limit is not None):
        raise ValueError(f"torque_limit must be a positive number, got {torque_limit!r}")
    if unusable:
        raise ValueError("saturate needs a torque limit: the robot has none (pass "
                         "torque_limit)")
    return float(lim) if lim.ndim == 0 else tuple(float(v) for v in lim)


def check_running_gait(gait, model=None, name: str | None = "gait"):
    """Refuse a running gait that no solve produces.

    Durations that are not positive finite numbers, states or torques that are not finite
    or of inconsistent shapes (and, with ``model``, not of that robot's size).

    Parameters
    ----------
    gait : RunningGait
        Or any object with its fields (module docstring).
    model : BipedModel, optional
        The robot it must fit.
    name : str or None
        How the gait is named in the message (None: the fields alone, as in a file).

    Raises
    ------
    ValueError
        One line naming the field.
    """
    def label(f):
        return f"'{f}'" if name is None else f"{name}.{f}"
    for f in ("T_stance", "T_flight"):
        v = getattr(gait, f)
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) \
                or not (math.isfinite(v) and v > 0):
            raise ValueError(f"{label(f)} must be a positive number of seconds, got {v!r}")
    a = {f: _number_array(label(f), getattr(gait, f)) for f in _FIELDS[2:]}
    for f, v in a.items():
        if v.ndim != 2 or v.shape[0] < 1 or v.shape[1] < 3 or v.shape[1] % 2 != 1:
            raise ValueError(f"{label(f)} must be a table of 2 n + 1 columns (n >= 1), got "
                             f"shape {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{label(f)} has non-finite entries (NaN or inf)")
    ns, cs = a["x_stance"].shape
    if model is None and ns % 2:
        raise ValueError(f"{label('x_stance')} must have 2 nq rows (q, dq), got {ns}")
    nq, nu = (model.nq, model.nu) if model is not None else (ns // 2, a["u_stance"].shape[0])
    cf = a["x_flight"].shape[1]
    want = dict(x_stance=(2 * nq, cs), u_stance=(nu, cs), x_flight=(2 * nq + 4, cf),
                u_flight=(nu, cf))
    robot = f" for {model.description.name} (nq = {nq})" if model is not None else ""
    for f, shape in want.items():
        if a[f].shape != shape:
            raise ValueError(f"{label(f)} has shape {a[f].shape}, {shape} expected{robot}")


def _gain(name, value, nu) -> np.ndarray:
    v = np.atleast_1d(_number_array(name, value)).ravel()
    if v.size == 1:
        v = np.repeat(v, nu)
    if v.size != nu or not np.all(np.isfinite(v)) or np.any(v < 0):
        raise ValueError(f"{name} must be one number or {nu} numbers, finite and >= 0, "
                         f"got {value!r}")
    return v


class RunningController:
    """Tracking of a running gait in stance and flight (module docstring).

    Parameters
    ----------
    model : BipedModel
        The robot the gait was optimised for (its dynamics give the reference's
        accelerations and the computed torque).
    gait : RunningGait
        The gait (or an object with its fields: ``T_stance``, ``T_flight``,
        ``x_stance``, ``u_stance``, ``x_flight``, ``u_flight``).
    Kp, Kd : float or array_like
        Gains, one number or one per output (nu), >= 0; units per ``law``.
    M1 : array_like, optional
        (nu,) the output's column on q1 (default 0: joint tracking).
    law : str
        'pd' (feedforward + PD, the default) or 'computed_torque'.
    saturate : bool
        Clip the torques at ``torque_limit``.
    torque_limit : float or tuple of float, optional
        N m, one number or one per torque u1 .. u_nu; default the model's (its
        ``description.torque_bound``: each joint's own where its joints' limits differ;
        inf for a robot without one: nothing to clip, and ``saturate`` then needs a
        finite ``torque_limit``).

    Attributes
    ----------
    stance, flight : PhaseReference
        The two references.
    M : numpy.ndarray
        (nu, nq) the output matrix [M1, I].
    gains : numpy.ndarray
        (3 nu,) (Kp, Kd, M1), the parameter k of the parametric laws.
    stance_law_k, flight_law_k : casadi.Function
        ``u(q, dq, t, k)`` (stance) and ``u(qe, dqe, t, k)`` (flight): the law's torques
        before saturation, N m, for any gains k = (Kp, Kd, M1).
    stance_law, flight_law : casadi.Function
        The same at this controller's gains: ``u(q, dq, t)``, ``u(qe, dqe, t)``.
    """

    def __init__(self, model, gait, Kp=400.0, Kd=30.0, M1=None, law: str = "pd",
                 saturate: bool = False, torque_limit=None):
        missing = [f for f in _FIELDS if not hasattr(gait, f)]
        if missing:
            raise TypeError(f"a running gait is needed (fields {', '.join(missing)} "
                            f"missing): gait_opt.running.optimize_running or RunningGait.load")
        if law not in LAWS:
            raise ValueError(f"law must be one of {', '.join(LAWS)}, got {law!r}")
        if not all(hasattr(model, a) for a in ("nq", "nu", "description", "forward_dynamics")):
            raise TypeError(f"model must be a robot model (biped_casadi.robot), got "
                            f"{type(model).__name__}")
        check_running_gait(gait, model)
        nq = model.nq
        self.model, self.gait, self.law = model, gait, law
        self.torque_limit = _torque_limit(model, torque_limit, saturate)
        self.saturate = bool(saturate)
        fl = flight_model(model)
        self.fl = fl
        Fs = phase_derivatives(model, "stance", gait.x_stance, gait.u_stance)
        Ff = phase_derivatives(model, "flight", gait.x_flight, gait.u_flight)
        self.stance = PhaseReference("stance", float(gait.T_stance), gait.x_stance, Fs,
                                     gait.u_stance, nq)
        self.flight = PhaseReference("flight", float(gait.T_flight), gait.x_flight, Ff,
                                     gait.u_flight, nq)
        self.stance_law_k = self._law("stance", nq)
        self.flight_law_k = self._law("flight", fl.ne)
        self._set_gains(Kp, Kd, M1)

    def _set_gains(self, Kp, Kd, M1):
        """Check and keep the gains; the two laws at them."""
        nq, nu = self.model.nq, self.model.nu
        self.Kp, self.Kd = _gain("Kp", Kp, nu), _gain("Kd", Kd, nu)
        m1 = np.zeros(nu) if M1 is None else _number_array("M1", M1).ravel()
        if m1.size != nu or not np.all(np.isfinite(m1)):
            raise ValueError(f"M1 must be {nu} finite numbers, got {M1!r}")
        check_M1_range(m1, "M1")
        self.M1 = m1
        self.M = np.hstack([m1[:, None], np.eye(nu)])
        self.gains = np.r_[self.Kp, self.Kd, self.M1]
        k = ca.DM(self.gains)
        for phase, n in (("stance", nq), ("flight", self.fl.ne)):
            q, dq, t = ca.SX.sym("q", n), ca.SX.sym("dq", n), ca.SX.sym("t")
            u = getattr(self, f"{phase}_law_k")(q, dq, t, k)
            setattr(self, f"{phase}_law", ca.Function(f"{phase}_running_law", [q, dq, t], [u],
                                                      ["q", "dq", "t"], ["u"]))

    def __repr__(self):
        return (f"RunningController({self.law}, Kp={self.Kp.tolist()}, Kd={self.Kd.tolist()}, "
                f"M1={self.M1.tolist()})")

    def with_gains(self, Kp=None, Kd=None, M1=None) -> "RunningController":
        """The same law and reference with other gains.

        Nothing is rebuilt but the two small Functions at the gains.

        Parameters
        ----------
        Kp, Kd, M1
            As the constructor; None keeps this controller's.

        Returns
        -------
        RunningController
        """
        new = copy.copy(self)
        new._set_gains(self.Kp if Kp is None else Kp, self.Kd if Kd is None else Kd,
                       self.M1 if M1 is None else M1)
        return new

    def _law(self, phase: str, n: int) -> ca.Function:
        """u(q, dq, t, k) of a phase, k = (Kp, Kd, M1)."""
        m, nq, nu = self.model, self.model.nq, self.model.nu
        ref = self.stance if phase == "stance" else self.flight
        q, dq, t = ca.SX.sym("q", n), ca.SX.sym("dq", n), ca.SX.sym("t")
        k = ca.SX.sym("k", 3 * nu)
        Kp, Kd, M1 = k[:nu], k[nu:2 * nu], k[2 * nu:]
        qd, dqd, ddqd, ud = ref(t)
        M = ca.horzcat(M1, ca.SX.eye(nu))
        e = ca.mtimes(M, qd - q[:nq])
        de = ca.mtimes(M, dqd - dq[:nq])
        if self.law == "pd":
            u = ud + Kp * e + Kd * de
        else:
            if phase == "stance":
                D, H, B = m.D(q), m.H(q, dq), ca.DM(m.B)
                Me = M
            else:
                D, H, B = self.fl.De(q), self.fl.He(q, dq), ca.DM(self.fl.Be)
                Me = ca.horzcat(M, ca.SX.zeros(nu, n - nq))
            a = ca.mtimes(M, ddqd) + Kp * e + Kd * de
            u = ca.solve(ca.mtimes(Me, ca.solve(D, B)), a + ca.mtimes(Me, ca.solve(D, H)))
        return ca.Function(f"{phase}_running_law_k", [q, dq, t, k], [u],
                           ["q", "dq", "t", "k"], ["u"])

    @property
    def clipped_at(self):
        """The limit the torques are clipped at, N m (None without ``saturate``).

        One number, or a tuple of one per torque where the joints' limits differ."""
        return self.torque_limit if self.saturate else None

    def applied(self, u):
        """The torques the robot receives: ``u`` clipped at the limit when ``saturate``.

        As :func:`~biped_casadi.control.saturation.clip_torques`: a NaN stays NaN.

        Parameters
        ----------
        u : casadi.SX or array_like
            The law's torques.

        Returns
        -------
        Same kind as ``u``.
        """
        if not self.saturate:
            return u
        return clip_torques(u, self.torque_limit)

    def applied_law(self, phase: str, name: str | None = None) -> ca.Function:
        """A phase's law with its torques as the robot receives them (:meth:`applied`).

        Parameters
        ----------
        phase : {'stance', 'flight'}
            The phase.
        name : str, optional
            The Function's name (default ``'<phase>_applied'``).

        Returns
        -------
        casadi.Function
            ``u(q, dq, t)`` (flight: ``u(qe, dqe, t)``, the extended coordinates).
        """
        law = getattr(self, f"{phase}_law")
        n = law.size1_in(0)
        q, dq, t = ca.SX.sym("q", n), ca.SX.sym("dq", n), ca.SX.sym("t")
        names = ["q", "dq", "t"] if phase == "stance" else ["qe", "dqe", "t"]
        return ca.Function(name or f"{phase}_applied", [q, dq, t],
                           [self.applied(law(q, dq, t))], names, ["u"])
