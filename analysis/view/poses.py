"""The robot of a run in 3-D, at every logged instant: what ``biped view`` draws.

The plane of motion is x-z (x forward, z up, as the model's coordinates); the two legs
stand :data:`DEPTH` in front of and behind it (y), each keeping its side from step to
step while its role alternates at every impact: in step k the stance leg is the leg on
the side (-1)^k DEPTH.  The torso stands in the plane, on an axle joining the two hips.
Every link is a segment between two points of the model (``model.points``), shifted
by the world position of the stance foot; a segment's pose for a cylinder whose axis is
its local z is its middle, the rotation taking z onto it and its length.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["DEPTH", "Segment", "WalkPoses", "walk_poses", "segment_frames"]

#: distance of each leg from the plane of motion, m
DEPTH = 0.06
#: radii of the drawn parts, m
LEG_RADIUS, TORSO_RADIUS, AXLE_RADIUS, JOINT_RADIUS, HEAD_RADIUS = 0.022, 0.035, 0.014, \
    0.03, 0.055


@dataclass
class Segment:
    """One drawn link over a run.

    Parameters
    ----------
    role : str
        'stance', 'swing' or 'torso' (its colour).
    radius : float
        Of its cylinder, m.
    a, b : numpy.ndarray
        (N, 3) its two ends at every logged instant, m.
    """

    role: str
    radius: float
    a: np.ndarray
    b: np.ndarray


@dataclass
class WalkPoses:
    """The robot of a run in 3-D at every logged instant of it.

    Parameters
    ----------
    t : numpy.ndarray
        (N,) time since the start of the run, s (an impact has two instants at one t).
    step : numpy.ndarray
        (N,) the step of each instant (0-based).
    segments : dict
        Name -> :class:`Segment` (links of the stance leg, the swing leg, the torso and
        the hip axle).
    joints : dict
        Name -> (role, radius, (N, 3) position): the joints, the feet and the head.
    footprints : numpy.ndarray
        (M, 3) every stance foot of the run, the first one and each landing.
    hip : numpy.ndarray
        (N, 3) the hip, in the plane of motion.
    """

    t: np.ndarray
    step: np.ndarray
    segments: dict = field(default_factory=dict)
    joints: dict = field(default_factory=dict)
    footprints: np.ndarray = None
    hip: np.ndarray = None

    @property
    def duration(self) -> float:
        """The time of the last instant, s."""
        return float(self.t[-1])

    def index(self, time: float) -> int:
        """The last instant at or before ``time`` (after an impact at that time).

        Parameters
        ----------
        time : float
            Seconds since the start of the run.

        Returns
        -------
        int
        """
        k = int(np.searchsorted(self.t, time, side="right")) - 1
        return min(max(k, 0), self.t.size - 1)


def walk_poses(res, model) -> WalkPoses:
    """The 3-D poses of a full-order run.

    Parameters
    ----------
    res : SimulationResult
        A run of :func:`biped_casadi.simulate` (with its logs).
    model : BipedModel
        Its robot.

    Returns
    -------
    WalkPoses
    """
    if res.t.size == 0:
        raise ValueError("res: the run has no logged states to draw")
    n = res.t.size
    npts = model.points.size2_out(0)
    P = np.array(model.points.map(n)(res.q.T)).reshape(2, npts, n, order="F")
    x = P[0].T + res.stance_x[:, None]               # (N, npts)
    z = P[1].T
    side = np.where(res.step % 2 == 0, DEPTH, -DEPTH)[:, None]     # the stance leg's y

    def at(i, y):
        return np.stack([x[:, i], np.broadcast_to(y, (n, 1))[:, 0], z[:, i]], axis=1)

    st, sw, to = model.stance_chain, model.swing_chain, model.torso_chain
    poses = WalkPoses(res.t.copy(), res.step.astype(int).copy())
    for role, chain, y in (("stance", st, side), ("swing", sw, -side)):
        for j, (p, q) in enumerate(zip(chain[:-1], chain[1:])):
            poses.segments[f"{role}_{j}"] = Segment(role, LEG_RADIUS, at(p, y), at(q, y))
        for p in chain:
            poses.joints[f"{role}_{model.point_names[p]}"] = (role, JOINT_RADIUS, at(p, y))
    hip, top = to
    zero = np.zeros((n, 1))
    poses.segments["torso"] = Segment("torso", TORSO_RADIUS, at(hip, zero), at(top, zero))
    poses.segments["axle"] = Segment("torso", AXLE_RADIUS, at(hip, -DEPTH + zero),
                                     at(hip, DEPTH + zero))
    poses.joints["head"] = ("torso", HEAD_RADIUS, at(top, zero))
    poses.hip = at(hip, zero)
    prints = np.r_[0.0, np.cumsum([s.step_length for s in res.steps])]
    sides = DEPTH * (-1.0) ** np.arange(prints.size)
    poses.footprints = np.stack([prints, sides, np.zeros_like(prints)], axis=1)
    return poses


def segment_frames(a, b) -> tuple:
    """Poses of cylinders (axis: their local z) spanning the segments from ``a`` to ``b``.

    Parameters
    ----------
    a, b : array_like
        (N, 3) or (3,) the ends.

    Returns
    -------
    tuple
        (position (N, 3): the middles, wxyz (N, 4): unit quaternions taking z onto b - a,
        length (N,)).
    """
    a, b = np.atleast_2d(np.asarray(a, float)), np.atleast_2d(np.asarray(b, float))
    d = b - a
    length = np.linalg.norm(d, axis=1)
    u = d / np.where(length > 0, length, 1.0)[:, None]
    # the rotation taking e_z onto u: the half-way quaternion (1 + e_z.u, e_z x u)
    q = np.stack([1.0 + u[:, 2], -u[:, 1], u[:, 0], np.zeros(len(u))], axis=1)
    flip = q[:, 0] < 1e-9                           # u = -e_z: half a turn about x
    q[flip] = (0.0, 1.0, 0.0, 0.0)
    q /= np.linalg.norm(q, axis=1)[:, None]
    return (a + b) / 2, q, length
