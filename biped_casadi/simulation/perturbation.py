"""Initial errors as data: the paper's perturbation, per-joint errors, sign patterns and
seeded random directions of the same per-joint size.

A push is an impulse on the robot: :func:`torso_push` is a horizontal impulse at the
torso's centre of mass, taken like an impact (instantaneous, the stance foot pinned,
the actuators producing no impulse).

A perturbation is added to the reference state at tau = 0 (the start of a step, just
after an impact).  Robustness is measured along *directions*: a direction d has 2 nq
components, and at scale s the initial error is (s q_size d[:nq], s dq_size d[nq:]),
with the paper's sizes q_size = 0.01 rad and dq_size = 0.1 rad/s (§V-C, Fig. 5).  The
paper's own perturbation is the all-positive direction d = (1, ..., 1) at s = 1.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..caching import cached
from ..control.reference import require_reference
from ..numerics import as_number, as_rows, as_vector

__all__ = ["Perturbation", "perturbed_initial_state", "directions", "direction_errors", "start_states", "PAPER_SIZES",
           "torso_push"]

#: the per-joint sizes of the paper's perturbation: 0.01 rad and 0.1 rad/s (§V-C)
PAPER_SIZES = (0.01, 0.1)


@dataclass(frozen=True)
class Perturbation:
    """An initial error (q, dq) added to the reference at tau = 0.

    Parameters
    ----------
    q : tuple of float
        Error of every joint angle, rad.
    dq : tuple of float
        Error of every joint velocity, rad/s (same length as ``q``).
    """

    q: tuple
    dq: tuple

    def __post_init__(self):
        q = np.atleast_1d(np.asarray(self.q, dtype=float))
        n = q.size
        object.__setattr__(self, "q", tuple(as_vector(q, n, "q").tolist()))
        object.__setattr__(self, "dq", tuple(as_vector(self.dq, n, "dq").tolist()))

    @classmethod
    def uniform(cls, nq: int, q_error: float, dq_error: float) -> "Perturbation":
        """The same error on every joint (``--perturb Q DQ``).

        Parameters
        ----------
        nq : int
            Joints of the robot.
        q_error : float
            Added to every joint angle, rad.
        dq_error : float
            Added to every joint velocity, rad/s.

        Returns
        -------
        Perturbation
        """
        q = as_number(q_error, "q_error")
        dq = as_number(dq_error, "dq_error")
        return cls((q,) * nq, (dq,) * nq)

    @classmethod
    def paper(cls, nq: int = 5) -> "Perturbation":
        """The paper's Fig. 5 perturbation: +0.01 rad on every joint, +0.1 rad/s on each rate.

        Parameters
        ----------
        nq : int
            Joints of the robot (5 for RABBIT).

        Returns
        -------
        Perturbation
        """
        return cls.uniform(nq, *PAPER_SIZES)

    @classmethod
    def from_direction(cls, d, scale: float = 1.0, sizes=PAPER_SIZES) -> "Perturbation":
        """The error s (q_size d[:nq], dq_size d[nq:]) of direction ``d`` at scale s.

        Parameters
        ----------
        d : array_like
            A direction of 2 nq components (see :func:`directions`).
        scale : float
            s >= 0.
        sizes : tuple of float
            (q_size, dq_size), rad and rad/s per unit component (default the paper's
            0.01 and 0.1).

        Returns
        -------
        Perturbation
        """
        d = np.asarray(d, dtype=float).ravel()
        if d.size % 2 or d.size == 0:
            raise ValueError(f"d must have 2 nq components, got {d.size}")
        d = as_vector(d, d.size, "d")
        s = as_number(scale, "scale", nonnegative=True)
        q, dq = direction_errors(d[None, :], s, sizes)
        return cls(tuple(q[0]), tuple(dq[0]))

    @property
    def nq(self) -> int:
        """Number of joints."""
        return len(self.q)

    def scaled(self, s: float) -> "Perturbation":
        """This perturbation times ``s``.

        Parameters
        ----------
        s : float
            The factor.

        Returns
        -------
        Perturbation
        """
        s = as_number(s, "scale")
        return Perturbation(tuple(s * v for v in self.q), tuple(s * v for v in self.dq))

    def initial_state(self, reference):
        """The perturbed start (q^d(0) + q, dq^d(0) + dq) of a reference.

        Parameters
        ----------
        reference : Reference
            Made for a robot with ``nq`` joints.

        Returns
        -------
        tuple of numpy.ndarray
            (q, dq), each (nq,).
        """
        if reference.model.nq != self.nq:
            raise ValueError(f"perturbation: {self.nq} joints, the robot has "
                             f"{reference.model.nq}")
        q0, dq0 = _add_to_start(reference, np.array(self.q)[None, :], np.array(self.dq)[None, :])
        return q0[0], dq0[0]

    def to_dict(self) -> dict:
        """The two error vectors as lists.

        Returns
        -------
        dict
            ``q`` (rad) and ``dq`` (rad/s).
        """
        return dict(q=list(self.q), dq=list(self.dq))


def directions(n: int, nq: int = 5, seed: int = 2024) -> np.ndarray:
    """``n`` perturbation directions (rows of 2 nq numbers), reproducible from ``seed``.

    Row 0 is the paper's all-positive direction; then, alternately, a random sign pattern
    (every component +-1) and a Gaussian random direction scaled to the length of a sign
    pattern (sqrt(2 nq)), so every direction has the paper's per-joint size on average.

    Parameters
    ----------
    n : int
        Number of directions (>= 1).
    nq : int
        Joints of the robot.
    seed : int
        Seed of the generator.

    Returns
    -------
    numpy.ndarray
        Shape (n, 2 nq).
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"n (number of directions) must be a positive integer, got {n!r}")
    if isinstance(nq, bool) or not isinstance(nq, (int, np.integer)) or nq < 1:
        raise ValueError(f"nq (joints) must be a positive integer, got {nq!r}")
    rng = np.random.default_rng(seed)
    out = [np.ones(2 * nq)]
    while len(out) < n:
        if len(out) % 2:
            out.append(rng.choice([-1.0, 1.0], 2 * nq))
        else:
            v = rng.standard_normal(2 * nq)
            out.append(v / np.linalg.norm(v) * math.sqrt(2 * nq))
    return np.array(out)


def direction_errors(dirs, scales, sizes=PAPER_SIZES):
    """The initial errors of directions at scales: (s q_size d[:nq], s dq_size d[nq:]).

    Parameters
    ----------
    dirs : array_like
        (n, 2 nq) directions (:func:`directions`).
    scales : float or array_like
        (n,) scales s, broadcast along the directions.
    sizes : tuple of float
        (q_size, dq_size): rad and rad/s per unit component (default the paper's 0.01
        and 0.1).

    Returns
    -------
    tuple of numpy.ndarray
        (q errors, dq errors), each (n, nq).
    """
    dirs = np.atleast_2d(np.asarray(dirs, float))
    nq = dirs.shape[1] // 2
    s = np.broadcast_to(np.asarray(scales, float), (len(dirs),))[:, None]
    return s * sizes[0] * dirs[:, :nq], s * sizes[1] * dirs[:, nq:]


def _add_to_start(reference, q_err, dq_err):
    return reference.q(0.0)[None, :] + q_err, reference.dq(0.0)[None, :] + dq_err


def start_states(reference, dirs, scales, sizes=PAPER_SIZES):
    """Start states (q0, dq0) of perturbation directions at given scales.

    The perturbation of a direction d at scale s (:func:`direction_errors`) is added to
    the reference at the start of the step (tau = 0).

    Parameters
    ----------
    reference : Reference
        The reference step.
    dirs : array_like
        (n, 2 nq) directions (one direction (2 nq,) is a batch of one).
    scales : float or array_like
        (n,) scales, broadcast along the directions.
    sizes : tuple of float
        Per-joint perturbation size at scale 1: rad for the angles, rad/s for the
        velocities (default the paper's 0.01 rad and 0.1 rad/s).

    Returns
    -------
    q0, dq0 : numpy.ndarray
        (n, nq) start configurations (rad) and velocities (rad/s).
    """
    nq = require_reference(reference).model.nq
    return _add_to_start(reference, *direction_errors(as_rows(dirs, 2 * nq, "dirs"), scales,
                                                      sizes))


@cached(maxsize=8)
def torso_push(model) -> ca.Function:
    """The velocity jump of a horizontal push on the torso.

    An impulse (P, 0) (N s, positive forward) at the torso's centre of mass, with the
    stance foot pinned and the actuators producing no impulse (like the impact of the theory
    §1): D(q) (dq+ - dq) = J_torso(q)' (P, 0).

    Parameters
    ----------
    model : BipedModel
        The robot.

    Returns
    -------
    casadi.Function
        ``torso_push(q, dq, P) -> dq_plus``.
    """
    q, dq, P = ca.SX.sym("q", model.nq), ca.SX.sym("dq", model.nq), ca.SX.sym("P")
    pts = model.points(q)
    hip, top = pts[:, model.hip_index], pts[:, model.hip_index + 1]
    t = model.description.torso
    com = hip + (t.com / t.length) * (top - hip)
    if t.com_offset != 0.0:                            # off the torso's line: forward normal
        com = com + (t.com_offset / t.length) * ca.vertcat(top[1] - hip[1], hip[0] - top[0])
    J = ca.jacobian(com, q)
    dq_plus = dq + ca.solve(model.D(q), ca.mtimes(J.T, ca.vertcat(P, 0)))
    return ca.Function("torso_push", [q, dq, P], [dq_plus], ["q", "dq", "P"], ["dq_plus"])


def perturbed_initial_state(gait, q_error=0.0, dq_error=0.0):
    """A perturbed start (q, dq) = (q^d(0) + q_error, dq^d(0) + dq_error).

    Parameters
    ----------
    gait : Reference
        The reference; its state at tau = 0 is perturbed.
    q_error, dq_error : float or array_like
        A number added to every joint (paper §V-C: 0.01 rad and 0.1 rad/s) or one
        number per joint.

    Returns
    -------
    tuple of numpy.ndarray
        (q, dq), each (nq,).
    """
    nq = require_reference(gait).model.nq
    if np.ndim(q_error) == 0 and np.ndim(dq_error) == 0:
        pert = Perturbation.uniform(nq, q_error, dq_error)
    else:
        def err(e, name):
            return np.full(nq, as_vector([e], 1, name)[0]) if np.ndim(e) == 0 \
                else as_vector(e, nq, name)
        pert = Perturbation(tuple(err(q_error, "q_error")), tuple(err(dq_error, "dq_error")))
    return pert.initial_state(gait)
