"""Restricted Poincaré map of the virtual-constraint (HZD) controller and its eigenvalue,
for the comparison of paper §V-C.

On the constraint surface Z = {H0 q = h_d(theta)}, theta = c q, the configuration is a
function of the phase alone, q = Q(theta) = [H0; c]^-1 [h_d(theta); theta], and the
zero dynamics is the unactuated row of eq. (1) along that curve:

    D_1(Q) (Q' ddtheta + Q'' dtheta^2) + H_1(Q, Q' dtheta) = 0.

theta being strictly monotonic, it is used as the independent variable: the state on Z
is w = dtheta, with dw/dtheta = ddtheta / w.  The impact on Z happens at the fixed phase
theta^- where z_sw(Q(theta)) = 0 (found with ``casadi.rootfinder``), whatever the
velocity: so the hybrid zero dynamics has a one-dimensional restricted Poincaré map.
Section: theta_s = c q^d(0.75 T) (the time-varying controller's section, docs: theory §4, seen
on the same orbit).  One application: integrate w from theta_s to theta^- (RK4 in
theta), apply the impact map and relabelling, theta^+ = c q^+, w^+ = c dq^+, integrate
from theta^+ back to theta_s.  Its derivative at the fixed point, by AD through the
whole discrete map, is the eigenvalue.

Cross-check (Westervelt, Grizzle et al., the HZD book, ch. 5-6): with the angular
momentum about the stance foot sigma = D_1(q) dq, sigma^2 / 2 obeys an exactly
integrable equation on Z, and the map is affine in it with slope delta_zero^2, where
delta_zero = sigma^+ / sigma^- across the impact of the orbit.  delta_zero depends only
on the impact configuration and velocity direction of the orbit, not on the outputs
or phase variable chosen: for one orbit the eigenvalue is the same for every choice
(paper §V-C, "the stability of an orbit is independent of the choice of the output").
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from biped_casadi import require_same_robot
from biped_casadi.caching import cached
from biped_casadi.control.virtual_constraints import (ConstraintSurface, VirtualConstraints,
                                                     constraint_surface)
from biped_casadi.control.output_law import SECTION
from biped_casadi.control.reference import require_reference
from biped_casadi.numerics import as_vector
from biped_casadi.results import Result

from .poincare import FIXED_POINT_TOL

__all__ = ["VCEigenResult", "VirtualConstraintMap", "vc_eigenvalue", "vc_map"]


@dataclass
class VCEigenResult(Result):
    """The restricted Poincaré map of a virtual-constraint controller at its fixed point.

    The map is one-dimensional (the hybrid zero dynamics of virtual constraints has the
    state dtheta on the section).  ``success`` means the eigenvalue was computed
    (stable or unstable).

    Parameters
    ----------
    eigenvalue : float
        dP/dw at the fixed point (AD through the discrete map).
    status : str
        'stable' (``|eigenvalue|`` < 1), 'unstable', 'singular', 'no_impact' or
        'open_orbit': the HZD orbit found is not the reference's (``orbit_mismatch``),
        the constraints are not impact invariant on it, or Newton did not close it
        (``fixed_point_residual``), beyond ``FIXED_POINT_TOL``; the gait is then not a
        periodic orbit of the model and the eigenvalue is that of another orbit.
    theta_section : float
        The section's phase, theta = c q^d(0.75 T), rad.
    theta_plus, theta_minus : float
        Phase just after and just before the impact of the HZD orbit, rad.
    w_star : float
        dtheta at the section on the HZD orbit (the fixed point), rad/s.
    x_star : numpy.ndarray
        (q_u, dq_u) there.
    reference_x : numpy.ndarray
        The reference's (q_u^d, dq_u^d)(0.75 T).
    orbit_mismatch : float
        max ``|x_star - reference_x|``: how exactly the constraints reproduce the
        reference orbit.
    fixed_point_residual : float
        ``|P(w*) - w*|``.
    delta_zero_squared : float
        The closed-form eigenvalue from the angular momentum about the stance foot
        (module docstring of :mod:`analysis.stability.vc_map`).
    min_denominator : float
        Smallest ``|D_1 Q'(theta)|`` on the step (zero: the controller is singular).
    constraints : dict
        The constraints' :meth:`~biped_casadi.VirtualConstraints.to_dict`.
    message : str
        What was found, or why the eigenvalue is undefined.
    """
    eigenvalue: float
    status: str
    theta_section: float
    theta_plus: float
    theta_minus: float
    w_star: float
    x_star: np.ndarray
    reference_x: np.ndarray
    orbit_mismatch: float
    fixed_point_residual: float
    delta_zero_squared: float
    min_denominator: float
    constraints: dict = field(default_factory=dict)
    message: str = ""

    SUCCESS = ("stable", "unstable")

    @property
    def max_abs(self) -> float:
        """``|eigenvalue|``, the counterpart of :attr:`PoincareResult.max_abs`."""
        return abs(self.eigenvalue)

    @property
    def eigenvalues(self) -> np.ndarray:
        """The eigenvalue as a one-element array."""
        return np.array([self.eigenvalue])

    def to_dict(self) -> dict:
        """The result in JSON types (what ``biped eig --controller vc --json`` prints).

        Returns
        -------
        dict
            The fields, plus ``controller`` 'vc', ``max_abs`` and ``eigenvalues`` as
            [re, im] pairs (as for the time-varying controller).
        """
        return dict(super().to_dict(), controller="vc", max_abs=self.max_abs,
                    eigenvalues=[[self.eigenvalue, 0.0]])


class VirtualConstraintMap:
    """The 1-D restricted Poincaré map P(w) of virtual constraints and its derivative.

    The CasADi Functions are built once.  ``evaluate(w)`` -> P(w); ``derivative(w)`` ->
    dP/dw; ``analyse()`` -> :class:`VCEigenResult`.

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : Reference
        The reference the constraints were fitted to.
    constraints : VirtualConstraints
        From :func:`biped_casadi.fit_virtual_constraints`.
    n_steps : int
        RK4 steps in theta over one step (>= 20).
    surface : ConstraintSurface, optional
        The constraints' surface, when already built.
    """

    def __init__(self, model, gait, constraints: VirtualConstraints, n_steps: int = 1000,
                 surface: ConstraintSurface | None = None):
        require_same_robot(model, gait)
        if not isinstance(constraints, VirtualConstraints):
            raise ValueError("constraints must be a VirtualConstraints")
        if not isinstance(n_steps, int) or n_steps < 20:
            raise ValueError(f"n_steps must be an integer >= 20, got {n_steps!r}")
        self.model, self.gait, self.vc = model, gait, constraints
        self.n_steps = n_steps
        self.T = gait.T
        self.surface = ConstraintSurface(model, constraints) if surface is None else surface
        s = self.surface
        self.curve, self.foot, self.rk4 = s.curve, s.foot, s.rk4
        self.theta_minus, self.theta_plus = s.theta_minus, s.theta_plus
        self.theta_s = s.phase(gait.q(SECTION * self.T))
        self.reference_x = gait.state_at(SECTION * self.T)
        self._build_map()

    # ------------------------------------------------------------------ map
    def _build_map(self):
        m, vc = self.model, self.vc
        span = self.theta_minus - self.theta_plus
        self.n_pre = max(4, int(round(self.n_steps * (self.theta_minus - self.theta_s) / span)))
        self.n_post = max(4, self.n_steps - self.n_pre)
        w = ca.MX.sym("w")
        acc_pre = self.rk4.mapaccum("hzd_pre", self.n_pre, [0, 1], [0, 1])
        acc_post = self.rk4.mapaccum("hzd_post", self.n_post, [0, 1], [0, 1])
        W, _ = acc_pre(w, self.theta_s, (self.theta_minus - self.theta_s) / self.n_pre)
        w_m = W[-1]
        q_m, Q1_m, _ = self.curve(self.theta_minus)
        q_p, dq_p = m.impact(q_m, Q1_m * w_m)
        w_p = ca.mtimes(ca.DM(vc.c).T, dq_p)
        W2, _ = acc_post(w_p, self.theta_plus, (self.theta_s - self.theta_plus) / self.n_post)
        w_next = W2[-1]
        self.map = ca.Function("hzd_poincare_map", [w], [w_next, ca.jacobian(w_next, w), w_m, w_p],
                               ["w"], ["w_next", "dP_dw", "w_minus", "w_plus"])

    def evaluate(self, w) -> float:
        """One application of the map.

        Parameters
        ----------
        w : float
            dtheta at the section, rad/s.

        Returns
        -------
        float
            P(w): dtheta at the section one step later, rad/s.
        """
        return float(self.map(w)[0])

    def derivative(self, w) -> float:
        """The map's derivative, by AD through the discrete map.

        Parameters
        ----------
        w : float
            dtheta at the section, rad/s.

        Returns
        -------
        float
            dP/dw at ``w``.
        """
        return float(self.map(w)[1])

    # -------------------------------------------------------------- analysis
    def _checks(self) -> tuple[str, str, float]:
        """Singularity of the zero dynamics and validity of the impact on the orbit."""
        n = 801
        ths = np.linspace(self.theta_plus, self.theta_minus, n)
        _, _, den = (np.array(v).ravel() for v in self.curve.map(n)(ths[None, :]))
        min_den = float(np.min(np.abs(den)))
        if den.min() * den.max() <= 0:
            return "singular", "D_1 Q'(theta) vanishes on the step: the controller is singular", min_den
        xs, zs, dz = (np.array(v).ravel() for v in self.foot.map(n)(ths[None, :]))
        # legs without knees may graze the ground inside the step (scuffing ignored):
        # only the ground beyond the scuff zone counts
        counts = xs > self.model.scuff_zone if self.model.scuffing_ignored else np.ones(n, bool)
        if np.any((zs[1:-1] <= 0) & counts[1:-1]):
            return "no_impact", "the swing foot touches the ground inside the step", min_den
        if not (xs[-1] > 0 and dz[-1] * np.sign(self.theta_minus - self.theta_plus) < 0):
            return "no_impact", "the impact of the HZD orbit is not valid (x_sw > 0, moving down)", min_den
        return "", "", min_den

    def analyse(self) -> VCEigenResult:
        """The fixed point (Newton on P(w) - w) and the eigenvalue dP/dw there (AD).

        Returns
        -------
        VCEigenResult
            With the closed-form check ``delta_zero_squared``; status 'singular' or
            'no_impact' (eigenvalue NaN) when the zero dynamics or its impact is invalid.
        """
        m, vc = self.model, self.vc
        dqs = self.gait.dq(SECTION * self.T)
        w = float(vc.c @ dqs)
        status, message, min_den = self._checks()
        nan = math.nan
        common = dict(theta_section=self.theta_s, theta_plus=self.theta_plus,
                      theta_minus=self.theta_minus, reference_x=self.reference_x,
                      min_denominator=min_den, constraints=vc.to_dict())
        if status:
            return VCEigenResult(eigenvalue=nan, status=status, w_star=nan,
                                 x_star=np.full(2, nan), orbit_mismatch=nan,
                                 fixed_point_residual=nan, delta_zero_squared=nan,
                                 message=message, **common)
        for _ in range(12):
            wn, dP, _, _ = (float(v) for v in self.map(w))
            step = (wn - w) / (1.0 - dP)
            w += step
            if abs(step) < 1e-13 * max(1.0, abs(w)):
                break
        wn, dP, w_m, w_p = (float(v) for v in self.map(w))
        q, Q1, _ = (np.array(v).ravel() for v in self.curve(self.theta_s))
        x_star = np.array([q[0], Q1[0] * w])
        # closed-form check: delta_zero^2 from the angular momentum about the stance foot
        q_m, Q1_m, _ = (np.array(v).ravel() for v in self.curve(self.theta_minus))
        q_p, dq_p = (np.array(v).ravel() for v in m.impact(q_m, Q1_m))
        sigma_m = float(np.array(m.D(q_m))[0] @ Q1_m)
        sigma_p = float(np.array(m.D(q_p))[0] @ dq_p)
        delta2 = (sigma_p / sigma_m) ** 2
        mismatch = float(np.max(np.abs(x_star - self.reference_x)))
        worst = max(abs(wn - w), mismatch, vc.invariance_residual)
        status = "stable" if abs(dP) < 1 else "unstable"
        if not worst <= FIXED_POINT_TOL:
            status = "open_orbit"
            message = (f"the HZD orbit is not the reference's: |P(w*) - w*| = {abs(wn - w):.2e}, "
                       f"orbit mismatch {mismatch:.2e}, impact invariance {vc.invariance_residual:.2e} "
                       f"(> {FIXED_POINT_TOL:g}); the gait is not a periodic orbit of this model")
        else:
            message = (f"HZD orbit: dtheta at the section {w:.12g} rad/s "
                       f"(reference {float(vc.c @ dqs):.12g})")
        return VCEigenResult(eigenvalue=dP, status=status,
                             w_star=w, x_star=x_star,
                             orbit_mismatch=mismatch, fixed_point_residual=abs(wn - w),
                             delta_zero_squared=delta2, message=message, **common)


@cached(maxsize=8)
def vc_map(gait, phase=None, H0=None, n_steps: int = 1000) -> VirtualConstraintMap:
    """The :class:`VirtualConstraintMap` of constraints fitted to a gait, built once.

    Memoised by the gait's digest and the arguments.

    Parameters
    ----------
    gait : Reference
    phase : array_like, optional
        theta = ``phase`` q (default the model's ``hip_phase``).
    H0 : array_like, optional
        Outputs H0 q - h_d(theta) (default q_a).
    n_steps : int
        RK4 steps in theta over one step.

    Returns
    -------
    VirtualConstraintMap
    """
    model = require_reference(gait).model
    if phase is not None:
        phase = tuple(as_vector(phase, model.nq, "phase").tolist())
    surface = constraint_surface(gait, phase, H0)
    return VirtualConstraintMap(model, gait, surface.vc, n_steps, surface=surface)


def vc_eigenvalue(gait, constraints: VirtualConstraints | None = None,
                  phase=None, H0=None, n_steps: int = 1000) -> VCEigenResult:
    """Eigenvalue of the 1-D restricted Poincaré map of the virtual-constraint controller.

    Parameters
    ----------
    gait : Reference
        The reference step, made for ``model``.
    constraints : VirtualConstraints, optional
        Given constraints; otherwise fitted to ``gait`` with phase variable
        theta = ``phase`` q and outputs H0 q - h_d(theta).
    phase, H0 : array_like, optional
        See :func:`biped_casadi.fit_virtual_constraints`; the default phase is the
        model's ``hip_phase`` (the stance-foot-to-hip angle; RABBIT: q1 + q2 / 2, the
        three-link biped: q1).
    n_steps : int
        RK4 steps in theta over one step.

    Returns
    -------
    VCEigenResult
        The eigenvalue, its status and the fixed point.

    Raises
    ------
    TypeError
        ``gait`` not a gait (it was an AttributeError on ``gait.model``).
    """
    model = require_reference(gait).model
    if constraints is None:
        phase = tuple(as_vector(model.hip_phase if phase is None else phase, model.nq,
                                "phase").tolist())
        H0 = None if H0 is None else tuple(map(tuple, np.asarray(H0, float)))
        return vc_map(gait, phase, H0, n_steps).analyse()
    return VirtualConstraintMap(model, gait, constraints, n_steps).analyse()
