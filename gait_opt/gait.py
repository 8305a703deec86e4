"""The reference gait q^d(t): evaluation, physical checks, and a self-describing file."""
from __future__ import annotations

import json
import math
import os
import warnings
from pathlib import Path

import numpy as np

import casadi as ca

from biped_casadi import Reference
from biped_casadi.caching import cached, digest
from biped_casadi.files import atomic_path, file_path
from biped_casadi.numerics import as_numbers

from .files import (FORMAT, FORMAT_VERSION, GaitFileError, OpenOrbitWarning, gait_parts,
                    read_gait_file)
from . import gait_checks
from .options import GaitOptions
from .parametrisation import quintic_hermite, reference_dynamics

__all__ = ["Gait", "GaitFileError", "OpenOrbitWarning", "FORMAT", "FORMAT_VERSION",
           "ORBIT_TOL"]

#: the reference is tabulated (and so defined) on [-EXTENT_BEFORE * T, EXTENT * T]
EXTENT = 2.0
EXTENT_BEFORE = 0.5
#: a gait must be a periodic orbit of its own robot to this accuracy: the impact map
#: applied to (q^d(T), dq^d(T)) returns (q^d(0), dq^d(0)) within ORBIT_TOL (rad, rad/s)
#: and the swing foot is on the ground at T within ORBIT_TOL (m).  Optimised gaits close
#: to ~1e-12 (at round-off, up to ~1e-9, on an ill-conditioned robot: gait_opt.polish).
ORBIT_TOL = 1e-8


class Gait(Reference):
    """A cyclic reference step of duration ``T`` (docs: theory §2).

    It implements the reference interface :class:`biped_casadi.Reference`.  ``q(t)``, ``dq(t)``, ``ddq(t)``, ``u(t)``: t a float or array in [0, 2 T] (past T the
    reference continues smoothly: the Bezier polynomials of q_a^d evaluated past s = 1
    and q_u^d continued by the unactuated row; before 0, down to -T/2, the same row
    integrated backwards); shapes (nq,) / (nu,) or (nq, N) / (nu, N) (RABBIT: 5 and 4).
    The reference state of the interface is r = (q_u^d, dq_u^d).
    ``alpha`` (nu x (M+1)) Bezier coefficients of q_a^d in s = t / T; ``x0`` = (q_u^d(0),
    dq_u^d(0)).  ``step_length``, ``speed``, ``cost``; ``solver_stats``; ``check()``
    computes every physical and consistency figure on a dense grid.

    Gaits come from :func:`optimize_gait` or :meth:`load`; q_u^d
    is tabulated on [-T/2, 2 T] by RK4 (``options.polish_steps`` per T) at its first use.

    Parameters
    ----------
    model : BipedModel
        The robot.
    options : GaitOptions
        The problem the gait solves (its torque limit filled in from ``model``).
    alpha : array_like
        (nu, bezier_degree + 1) Bezier coefficients of q_a^d(s), s = t / T, rad.
    x0 : array_like
        (q_u^d(0), dq_u^d(0)), rad and rad/s.
    T : float
        Step duration, s.
    solver_stats : dict, optional
        IPOPT's status, timings and the like (kept in files, not part of the gait's
        definition).
    """

    def __init__(self, model, options: GaitOptions, alpha, x0, T, solver_stats=None):
        self.model = model
        self.options = options.for_model(model)
        self.alpha = np.array(alpha, dtype=float).reshape(model.nu, options.bezier_degree + 1)
        self.x0 = np.array(x0, dtype=float).ravel()
        self.T = float(T)
        if self.x0.shape != (2,) or not np.all(np.isfinite(self.x0)) or not np.all(np.isfinite(self.alpha)):
            raise ValueError("gait: x0 must be 2 finite numbers and alpha finite")
        if not (math.isfinite(self.T) and self.T > 0):
            raise ValueError(f"gait: T must be positive, got {T!r}")
        self.solver_stats = dict(solver_stats or {})
        self._ref = reference_dynamics(model, options.bezier_degree, options.continuation,
                                       options.continuation_shape)
        self.n_state = 2
        self.r0 = self.x0
        self._key = None
        self._table = None                  # (s, X, A): tabulated at first use

    # --------------------------------------------------------------- tabulation
    def _integrate(self, n_steps, ds):
        """RK4 states of the unactuated row from x0 in steps ds (in s = t / T), cut
        where the passive continuation blows up: (s, X) including the start."""
        X = np.array(self._ref.integrate(n_steps)(self.x0, 0.0, ds, self.alpha, self.T))
        X = np.hstack([self.x0[:, None], X])
        s = np.arange(n_steps + 1) * ds
        finite = np.all(np.isfinite(X), axis=0)
        if not finite.all():
            last = int(np.argmin(finite)) - 1
            X, s = X[:, :last + 1], s[:last + 1]
        return s, X

    def _nodes(self) -> tuple:
        """(s, X, A): the grid in s = t / T, the RK4 states of the unactuated row there and
        its acceleration, tabulated at the first call (a gait only passed along, as in
        a process that schedules tasks, never integrates)."""
        if self._table is None:
            n = self.options.polish_steps
            s_f, X_f = self._integrate(int(round(EXTENT * n)), 1.0 / n)
            s_b, X_b = self._integrate(int(round(EXTENT_BEFORE * n)), -1.0 / n)
            s = np.r_[s_b[:0:-1], s_f]
            X = np.hstack([X_b[:, :0:-1], X_f])
            qa, dqa, ddqa = self._qa(s)
            q = np.vstack([X[0], qa])
            dq = np.vstack([X[1], dqa])
            A = np.array(self._ref.ddqu.map(s.size)(q, dq, ddqa)).ravel()
            self._table = (s, X, A)
        return self._table

    @property
    def t_min(self) -> float:
        """The earliest time of the reference, s (about -T/2)."""
        return float(self._nodes()[0][0] * self.T)

    @property
    def t_max(self) -> float:
        """The latest time of the reference, s.

        About 2 T, or where the unactuated row's continuation stops being finite.
        """
        return float(self._nodes()[0][-1] * self.T)

    def __reduce__(self):
        # pickled as its definition (the CasADi Functions are rebuilt, once per process)
        return (_rebuilt, (self.model, self.options, self.alpha, self.x0, self.T,
                           self.solver_stats))

    @property
    def cache_key(self) -> str:
        """SHA-256 of what defines the gait: robot, options and solution."""
        if self._key is None:
            self._key = digest(self.definition())
        return self._key

    def definition(self) -> dict:
        """What defines the reference (its digest is ``cache_key``).

        Returns
        -------
        dict
            ``format``, ``version``, ``robot``, ``options`` and ``solution`` of
            :meth:`to_dict` (without the solver's statistics).
        """
        d = self.to_dict()
        return {k: d[k] for k in ("format", "version", "robot", "options", "solution")}

    @cached(maxsize=16)
    def symbolic(self) -> ca.Function:
        """The reference as a CasADi Function ``(tau, r) -> (qd, dqd, ddqd, dr)``.

        r = (q_u^d, dq_u^d) is the reference state: q_a^d comes from the Bezier
        polynomials, q_u^d from r, ddq_u^d from the unactuated row of eq. (1) (see
        :class:`biped_casadi.Reference`).  Built once per gait.

        Returns
        -------
        casadi.Function
            Named inputs ``tau``, ``r`` and outputs ``qd``, ``dqd``, ``ddqd``, ``dr``.
        """
        tau = ca.SX.sym("tau")
        r = ca.SX.sym("r", 2)
        return ca.Function("reference", [tau, r], self._expressions(
            tau, r, ca.DM(self.alpha), self.T), ["tau", "r"], ["qd", "dqd", "ddqd", "dr"])

    def _expressions(self, tau, r, alpha, T):
        ref = self._ref
        qa, dqa, ddqa = ref.qa(alpha, tau / T, T)
        qd = ca.vertcat(r[0], qa)
        dqd = ca.vertcat(r[1], dqa)
        ddqu = ref.ddqu(qd, dqd, ddqa)
        return [qd, dqd, ca.vertcat(ddqu, ddqa), ca.vertcat(r[1], ddqu)]

    def symbolic_parametric(self):
        """The reference as a Function of its parameters too.

        The same Function for every gait with these options: the Bezier coefficients and
        T are an input.

        Returns
        -------
        f : casadi.Function
            ``(tau, r, theta) -> (qd, dqd, ddqd, dr)``, as :meth:`symbolic`.
        theta : numpy.ndarray
            This gait's parameters: the Bezier coefficients (column by column) and T.
        """
        nu, m1 = self.alpha.shape
        tau, r, th = ca.SX.sym("tau"), ca.SX.sym("r", 2), ca.SX.sym("theta", nu * m1 + 1)
        f = ca.Function("reference_parametric", [tau, r, th], self._expressions(
            tau, r, ca.reshape(th[:-1], nu, m1), th[-1]), ["tau", "r", "theta"],
            ["qd", "dqd", "ddqd", "dr"])
        return f, np.r_[self.alpha.ravel(order="F"), self.T]

    def _qa(self, s):
        s = np.atleast_1d(s)
        out = self._ref.qa.map(s.size)(self.alpha, s[None, :], self.T)
        return tuple(np.array(o) for o in out)

    def _check_times(self, t1):
        if not np.all(np.isfinite(t1)):
            raise ValueError("gait: t must be finite")
        if np.any(t1 < self.t_min - 1e-12) or np.any(t1 > self.t_max + 1e-12):
            raise ValueError(f"gait: t must lie in [{self.t_min:.6g}, {self.t_max:.6g}] "
                             f"(-T/2 to 2 T), got [{t1.min():.6g}, {t1.max():.6g}]")

    def evaluate(self, t):
        """q^d, dq^d, ddq^d at ``t`` (numeric).

        Parameters
        ----------
        t : float or array_like
            Time(s) in [t_min, t_max] = [-T/2, 2 T], s.

        Returns
        -------
        tuple of numpy.ndarray
            (q, dq, ddq) in rad, rad/s, rad/s^2; shapes (nq,) each for a float ``t``,
            (nq, N) for N times.

        Raises
        ------
        ValueError
            When a time is not finite or outside [t_min, t_max].
        """
        t_arr = as_numbers(t, "gait: t")
        scalar = t_arr.ndim == 0
        t1 = np.atleast_1d(t_arr).ravel()
        self._check_times(t1)
        if t1.size == 0:                     # no times: (nq, 0) each (CasADi maps need n > 0)
            return tuple(np.zeros((self.model.nq, 0)) for _ in range(3))
        sg, X, A = self._nodes()
        qu, dqu, _ = quintic_hermite(sg * self.T, X[0], X[1], A, t1)
        qa, dqa, ddqa = self._qa(t1 / self.T)
        q, dq = np.vstack([qu, qa]), np.vstack([dqu, dqa])
        # ddq_u from the unactuated row itself (the interpolant's second derivative would
        # lose ~1e-7 to cancellation), so eq. (1) row 1 holds to round-off at any t
        ddqu = np.array(self._ref.ddqu.map(t1.size)(q, dq, ddqa))
        res = (q, dq, np.vstack([ddqu, ddqa]))
        return tuple(r[:, 0] for r in res) if scalar else res

    def state(self, t) -> np.ndarray:
        """The reference state r(t) = (q_u^d(t), dq_u^d(t)).

        Parameters
        ----------
        t : float
            Time in [t_min, t_max], s.

        Returns
        -------
        numpy.ndarray
            Shape (2,): rad, rad/s.
        """
        return self.state_at(t)

    def states(self, t) -> np.ndarray:
        """The reference state r = (q_u^d, dq_u^d) at every time of an array.

        Parameters
        ----------
        t : array_like
            N times in [t_min, t_max], s.

        Returns
        -------
        numpy.ndarray
            Shape (2, N).
        """
        t1 = np.atleast_1d(as_numbers(t, "gait: t")).ravel()
        self._check_times(t1)
        sg, X, A = self._nodes()
        qu, dqu, _ = quintic_hermite(sg * self.T, X[0], X[1], A, t1)
        return np.vstack([qu, dqu])

    def state_nodes(self) -> tuple:
        """The nodes of the quintic Hermite interpolant that defines r(t) between them.

        Returns
        -------
        tuple of numpy.ndarray
            (t, q_u, dq_u, ddq_u), each (N,): the uniform grid on [t_min, t_max] (s) and
            the RK4 states of the unactuated row with its acceleration there; ``state(t)``
            is (y(t), y'(t)) of the quintic through (q_u, dq_u, ddq_u) at the two nodes
            around t.
        """
        sg, X, A = self._nodes()
        return (sg * self.T, X[0].copy(), X[1].copy(), A.copy())

    # ---------------------------------------------------------------- figures
    @property
    def step_length(self) -> float:
        """x of the swing foot at T, m: the distance covered in one step."""
        return float(self.model.swing_foot(self.q(self.T))[0])

    @property
    def speed(self) -> float:
        """Average forward speed, step length / T, m/s."""
        return self.step_length / self.T

    @property
    def cost(self) -> float:
        """Integral of u'u over the step divided by the step length (Simpson, 2001 pts)."""
        t = np.linspace(0, self.T, 2001)
        uu = np.sum(self.u(t)**2, axis=0)
        h = t[1] - t[0]
        integral = h / 3 * (uu[0] + uu[-1] + 4 * uu[1:-1:2].sum() + 2 * uu[2:-1:2].sum())
        return float(integral / (self.step_length if self.options.cost ==
                                 "torque_squared_per_length" else 1.0))

    def torso_lean(self, n: int = 201) -> float:
        """The torso's largest lean from upright over the step, rad.

        The lean is the torso's angle less the robot's upright angle
        (:attr:`~biped_casadi.model.description.RobotDescription.torso_upright`: 0, the
        vertical, unless the torso hangs below the hip), wrapped to [-pi, pi).  A gait past
        the simulator's fall bound
        (:attr:`biped_casadi.SimulationOptions.max_torso_angle`, pi/2) cannot be walked:
        every walk of it is a fall.

        Parameters
        ----------
        n : int
            Grid points on [0, T].

        Returns
        -------
        float
        """
        f, d = self.model.torso_angle, self.model.description
        return max(abs(float(d.torso_lean(float(f(self.q(t))))))
                   for t in np.linspace(0.0, self.T, n))

    def check(self, n: int = 2001) -> dict:
        """Physical validity and dynamic consistency on a dense grid of [0, T].

        Parameters
        ----------
        n : int
            Grid points.

        Returns
        -------
        dict
            ``max_abs_torque`` (N m; ``max_abs_torques`` per torque u1 .. u_nu),
            ``min_normal_force`` (N), ``max_friction_ratio``,
            ``min_swing_height_inside`` and ``min_clearance_margin`` (m, inside the
            step), ``swing_height_at_T`` (m), ``strike_velocity`` and
            ``liftoff_velocity`` (m/s), ``impact_impulse`` (N s) and
            ``impact_friction_ratio``, ``max_stance_knee`` / ``min_swing_knee`` (rad;
            None without knees), ``max_torso_lean`` (rad, as :meth:`torso_lean`),
            ``periodicity_q`` / ``periodicity_dq`` (the impact of
            the state at T against the state at 0) and ``unactuated_row_residual``
            (first row of eq. 1, N m), plus ``n_points``.
        """
        return gait_checks.dense_check(self, n)

    def reintegration_error(self, n: int = 201) -> float:
        """How well q_u^d solves the unactuated row of eq. (1), checked independently.

        The row is integrated by CVODES (tolerances 1e-13) from x0 with q_a = q_a^d(t)
        imposed.

        Parameters
        ----------
        n : int
            Grid points on [0, T] where the two are compared.

        Returns
        -------
        float
            max ``|q_u(t) - q_u^d(t)|`` on the grid, rad.
        """
        x = ca.SX.sym("x", 2)
        t = ca.SX.sym("t")
        qa, dqa, ddqa = self._ref.qa(self.alpha, t / self.T, self.T)
        q = ca.vertcat(x[0], qa)
        dq = ca.vertcat(x[1], dqa)
        ode = ca.vertcat(x[1], self._ref.ddqu(q, dq, ddqa))
        grid = np.linspace(0, self.T, n)
        F = ca.integrator("reintegrate", "cvodes", {"x": x, "t": t, "ode": ode}, 0.0, grid[1:],
                          {"abstol": 1e-13, "reltol": 1e-13, "max_num_steps": 100000})
        X = np.array(F(x0=self.x0)["xf"])
        return float(np.max(np.abs(X[0] - self.q(grid[1:])[0])))

    def violations(self, check: dict | None = None, tol: float = 1e-7) -> list:
        """Constraints of ``options`` violated on a dense grid, not only at the nodes.

        Parameters
        ----------
        check : dict, optional
            A result of :meth:`check` (computed when not given).
        tol : float
            Amounts up to this count as satisfied.

        Returns
        -------
        list of (str, float)
            (constraint family, worst amount), worst first; empty for a valid gait.
            Amounts in N m, N, m, m/s, rad; friction as a ratio.
        """
        return gait_checks.dense_violations(self, check or self.check(), tol)

    def bounds_hit(self, rtol: float = 1e-6) -> list:
        """The step-length and step-time bounds of the optimiser that the gait lies on.

        Its optimum lies beyond them (the default bounds are RABBIT's sizes).

        Parameters
        ----------
        rtol : float
            Relative distance from a bound that counts as on it.

        Returns
        -------
        list of list
            [option name, 'lower' or 'upper', bound] for each bound the gait lies on.
        """
        return gait_checks.bounds_hit(self, rtol)

    def summary(self) -> dict:
        """Every figure of the gait: physics on a dense grid and consistency.

        Returns
        -------
        dict
            T, step length, speed, cost, the figures of :meth:`check`, the
            :meth:`reintegration_error`, the dense-grid violations, the
            :meth:`bounds_hit` and the solver's
            status, iterations and time (what ``biped gait --json`` prints).
        """
        c = self.check()
        return dict(T=self.T, step_length=self.step_length, speed=self.speed, cost=self.cost,
                    peak_torque=c["max_abs_torque"], min_normal_force=c["min_normal_force"],
                    max_friction_ratio=c["max_friction_ratio"],
                    min_swing_height_inside=c["min_swing_height_inside"],
                    strike_velocity=c["strike_velocity"], liftoff_velocity=c["liftoff_velocity"],
                    impact_friction_ratio=c["impact_friction_ratio"],
                    max_stance_knee=c["max_stance_knee"], min_swing_knee=c["min_swing_knee"],
                    periodicity_q=c["periodicity_q"], periodicity_dq=c["periodicity_dq"],
                    swing_height_at_T=c["swing_height_at_T"],
                    unactuated_row_residual=c["unactuated_row_residual"],
                    reintegration_error=self.reintegration_error(),
                    dense_grid_points=c["n_points"],
                    dense_grid_violations=[list(v) for v in self.violations(c)],
                    bounds_hit=self.bounds_hit(),
                    solve_time=self.solver_stats.get("total_time"),
                    ipopt_iterations=self.solver_stats.get("iterations"),
                    ipopt_status=self.solver_stats.get("status"))

    # --------------------------------------------------------------- file I/O
    def to_dict(self) -> dict:
        """The gait file's content (without the checksum).

        Returns
        -------
        dict
            ``format``, ``version``, ``robot`` (the description), ``options``,
            ``solution`` (T, alpha, x0) and ``solver_stats``.
        """
        body = dict(format=FORMAT, version=FORMAT_VERSION,
                    robot=self.model.description.to_dict(), options=self.options.to_dict(),
                    solution=dict(T=self.T, alpha=self.alpha.tolist(), x0=self.x0.tolist()),
                    solver_stats=_jsonable(self.solver_stats))
        return body

    def save(self, path) -> Path:
        """Write the gait to a self-describing JSON file, atomically.

        The file holds the format, version, robot, options, solution and solver
        statistics, and a SHA-256 checksum of the rest; it is complete or absent.

        Parameters
        ----------
        path : str or Path
            The file to write (replaced if it exists).

        Returns
        -------
        Path
            ``path``.
        """
        path = file_path(path)
        body = self.to_dict()
        body["sha256"] = digest(body)
        text = json.dumps(body, indent=1)
        with atomic_path(path) as tmp:       # complete or absent; no stray temp file
            tmp.write_text(text)
        return path

    def orbit_residual(self) -> dict:
        """How far the gait is from a periodic orbit of its robot.

        Returns
        -------
        dict
            ``q`` = max|q+ - q^d(0)| (rad) and ``dq`` = max|dq+ - dq^d(0)| (rad/s), with
            (q+, dq+) the impact map and relabelling applied to (q^d(T), dq^d(T));
            ``z`` = ``|z_sw(T)|`` (m); ``worst`` the largest (inf when the gait cannot be
            evaluated at T).  :meth:`load` compares ``worst`` with :data:`ORBIT_TOL`.
        """
        with np.errstate(all="ignore"):
            try:
                qT, dqT = self.q(self.T), self.dq(self.T)
                q0, dq0 = self.q(0.0), self.dq(0.0)
                qp, dqp = (np.array(v).ravel() for v in self.model.impact(qT, dqT))
                z = abs(float(np.array(self.model.swing_foot(qT)).ravel()[1]))
                out = dict(q=float(np.max(np.abs(qp - q0))), dq=float(np.max(np.abs(dqp - dq0))),
                           z=z)
            except ValueError:            # the reference does not reach T
                out = dict(q=math.inf, dq=math.inf, z=math.inf)
        vals = [v if math.isfinite(v) else math.inf for v in out.values()]
        out["worst"] = max(vals)
        return out

    @classmethod
    def from_dict(cls, d: dict, model=None, *, where: str = "gait") -> "Gait":
        """The gait a dictionary describes: :meth:`definition`'s, or a gait file's body.

        The robot, options and solution are validated as in a file (:meth:`load`); the
        orbit is not checked here.

        Parameters
        ----------
        d : dict
            ``robot``, ``options`` and ``solution`` (T, alpha, x0), optionally
            ``solver_stats``.
        model : BipedModel, optional
            The dictionary must describe this robot (default: its own robot).
        where : str
            What the dictionary is, for the messages.

        Returns
        -------
        Gait

        Raises
        ------
        GaitFileError
            Naming ``where`` and what is wrong.
        """
        model, opts, (alpha, x0, T), stats = gait_parts(d, model, where)
        try:
            with np.errstate(all="ignore"):
                return cls(model, opts, alpha, x0, T, solver_stats=stats)
        except (ValueError, RuntimeError, FloatingPointError) as e:
            raise GaitFileError(f"{where}: the solution cannot be evaluated ({e})") from None

    @classmethod
    def load(cls, path, model=None, *, allow_open_orbit: bool = False,
             orbit_tol: float = ORBIT_TOL) -> "Gait":
        """Read and validate a gait file.

        Parameters
        ----------
        path : str or Path
            The gait file.
        model : BipedModel, optional
            The file must have been made for this robot (its description is recorded
            in the file; files written before robot descriptions record RABBIT-type
            flat parameters and load too).  Default: the file's robot.
        allow_open_orbit : bool
            A gait that is not a periodic orbit of its robot (see :meth:`orbit_residual`)
            is refused; with True it is returned with an :class:`OpenOrbitWarning`.
        orbit_tol : float
            The accuracy the orbit must close to (default :data:`ORBIT_TOL`).

        Returns
        -------
        Gait
            With the file's solver statistics.

        Raises
        ------
        GaitFileError
            For anything wrong, naming the file and the reason: missing, a folder,
            unreadable, not JSON, another format or version, checksum mismatch, a missing
            or unknown key, a wrong type, size or non-finite number, an invalid robot
            description, another robot, or not a periodic orbit.
        """
        if not isinstance(path, (str, os.PathLike)):
            raise GaitFileError(f"path must be a file name, got {type(path).__name__}")
        path = Path(path)
        return cls.from_record(read_gait_file(path), model, where=f"gait file {path}",
                               allow_open_orbit=allow_open_orbit, orbit_tol=orbit_tol)

    @classmethod
    def from_record(cls, body: dict, model=None, *, where: str = "gait",
                    allow_open_orbit: bool = False, orbit_tol: float = ORBIT_TOL) -> "Gait":
        """The gait of a gait file's body, validated as :meth:`load` does.

        The envelope (format, version, checksum) is checked already
        (:func:`gait_opt.files.gait_body`); here the robot, options, solution, and that
        the gait is a periodic orbit.

        Parameters
        ----------
        body : dict
            A gait file's content without its checksum
            (:func:`gait_opt.files.gait_body`).
        model : BipedModel, optional
            The robot the record must describe (default: its own).
        where : str
            What the record is, for the messages.
        allow_open_orbit, orbit_tol
            As :meth:`load`.

        Returns
        -------
        Gait

        Raises
        ------
        GaitFileError
            Naming ``where`` and what is wrong.
        """
        gait = cls.from_dict(body, model, where=where)
        T = gait.T
        try:
            with np.errstate(all="ignore"):
                r = gait.orbit_residual()
        except (ValueError, IndexError, OverflowError, FloatingPointError, RuntimeError):
            r = dict(worst=math.inf)              # a T of 1e-300 s: no grid to evaluate on
        if not math.isfinite(r["worst"]):
            # not even an open orbit: nothing of it can be analysed (with allow_open_orbit
            # the commands failed later on an IndexError or OverflowError)
            raise GaitFileError(f"{where} is not a periodic orbit of its robot: its motion "
                                f"cannot be evaluated up to T = {T:.6g} s; was T or the "
                                f"solution edited?")
        if not r["worst"] <= orbit_tol:
            msg = (f"{where} is not a periodic orbit of its robot: the impact of the state "
                   f"at T misses the start by {r['q']:.2g} rad / {r['dq']:.2g} rad/s and the "
                   f"swing foot is {r['z']:.2g} m off the ground at T (tolerance "
                   f"{orbit_tol:g}); was T or the solution edited?")
            if not allow_open_orbit:
                raise GaitFileError(msg)
            warnings.warn(msg, OpenOrbitWarning, stacklevel=2)
        return gait

    def __repr__(self):
        return (f"Gait(T={self.T:.4f} s, step={self.step_length:.4f} m, "
                f"speed={self.speed:.4f} m/s, robot={self.model.params.name})")


_REBUILT: dict = {}


def _rebuilt(model, options, alpha, x0, T, solver_stats):
    """A gait from its parts, tabulated once per process for one definition."""
    key = digest(dict(robot=model.cache_key, options=options.to_dict(),
                      alpha=np.asarray(alpha, float).tolist(), x0=np.asarray(x0, float).tolist(),
                      T=float(T)))
    g = _REBUILT.get(key)
    if g is None:
        g = Gait(model, options, alpha, x0, T, solver_stats)
        if len(_REBUILT) >= 64:
            _REBUILT.pop(next(iter(_REBUILT)))
        _REBUILT[key] = g
    return g


def _jsonable(d):
    return json.loads(json.dumps(d, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
