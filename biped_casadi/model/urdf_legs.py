"""The ends of a URDF's legs and how closely the two must agree: the foot point (a
fixed frame of the last link, a sole below a locked ankle, ``foot=``, ``foot_beyond``),
and the legs alike chains of joints, identical by default or within ``match_tol`` of
the leg's size (a CAD export's mirrored parts differ in their last digits), the model's
leg then their mean.
Used by :mod:`biped_casadi.model.urdf`."""
from __future__ import annotations

import math

import numpy as np

from .urdf_tree import _Frame, _parallel, _Reader

__all__ = ["MATCH_TOL", "MAX_MATCH_TOL", "check_match_tol"]

#: the legs' agreement by default (identical), and the widest match_tol taken: legs
#: that differ by more are two robots, not one robot's mirrored legs
MATCH_TOL, MAX_MATCH_TOL = 1e-9, 0.05


def _same_legs(rd, links, pms, legs, match_tol: float, hips: float = 0.0) -> float:
    """The legs agree within ``match_tol`` (relative to the leg's size, by quantity);
    the first leg's links become their mean where they differ (said in the notes).  A
    refusal names the largest difference and the tolerance that takes every one, the
    hips' (``hips``, relative) too.  Returns the largest difference taken."""
    span = sum(a["length"] for a in links[0])
    mass = sum(a["mass"] for a in links[0]) + sum(v for k, v in pms[0].items() if k != "hip")
    scale = dict(mass=mass, length=span, com=span, com_offset=span, inertia=mass * span ** 2)
    diffs = []
    for a, b in zip(*links):
        for key, size in scale.items():
            d = abs(a[key] - b[key])
            if d <= rd.tol or math.isclose(a[key], b[key], rel_tol=1e-12):
                continue
            diffs.append((d / size, d, key, a, b))
    big = max(diffs, key=lambda x: x[0], default=None)
    if big is not None and big[0] > match_tol:
        rel, d, key, a, b = big
        rd.fail(f"legs differ: link {a['name']!r} has {key} {a[key]:.12g}, link "
                f"{b['name']!r} {b[key]:.12g} (apart by {d:.2g}, {rel:.2g} of the "
                f"leg's {_SIZE[key]}){_wider(max(rel, hips), match_tol)}")
    worst = (0.0, "")
    for rel, d, key, a, b in diffs:
        worst = max(worst, (rel, f"{key} of {a['name']!r} and {b['name']!r}"))
        a[key] = 0.5 * (a[key] + b[key])
    if set(pms[0]) - {"hip"} != set(pms[1]) - {"hip"}:
        rd.fail(f"legs differ in their point masses (legs of {legs[0].joints[0].name!r} and "
                f"{legs[1].joints[0].name!r}): {pms[0]} and {pms[1]}")
    for k in set(pms[0]) - {"hip"}:
        rel = abs(pms[0][k] - pms[1][k]) / mass
        if rel > max(match_tol, 1e-12):
            rd.fail(f"legs differ in their point masses (legs of {legs[0].joints[0].name!r} "
                    f"and {legs[1].joints[0].name!r}): {pms[0]} and {pms[1]}"
                    f"{_wider(max(rel, hips, worst[0]), match_tol)}")
        if rel > 0:
            worst = max(worst, (rel, f"point mass at {k}"))
            pms[0][k] = 0.5 * (pms[0][k] + pms[1][k])
    if worst[0] > 0:
        rd.notes.append(f"the legs differ by up to {worst[0]:.2g} of the leg's size "
                        f"({worst[1]}; match_tol {match_tol:g}): the model's leg is their mean")
    return worst[0]


#: what each quantity of a leg is measured against in ``match_tol``
_SIZE = dict(mass="mass", length="length", com="length", com_offset="length",
             inertia="mass x length^2")


def _unequal_legs(rd: _Reader, torso: str, chains) -> None:
    """Refuse legs of different numbers of joints; when the shorter one hangs from a link
    welded to the torso (Drake's kneed compass gait: one thigh fixed to the hip, one pin
    between the thighs), say that such a walker has no torso of the model's kind."""
    short = min(chains, key=len)[0][0]
    welded = "" if short.parent == torso or abs(len(chains[0]) - len(chains[1])) != 1 else (
        f" ({short.name!r} hangs from link {short.parent!r}, fixed to the torso {torso!r}: "
        f"if that is a thigh welded to the hip, as in a compass-gait walker with one joint "
        f"between its thighs, the robot has no torso apart from its legs, which the model "
        f"needs to carry both legs by their hip joints)")
    rd.fail("legs differ: " + " and ".join(
        f"{len(c)} joint(s) ({' -> '.join(j.name for j, _ in c)})" for c in chains)
        + ": the model's two legs are alike chains of joints from the torso" + welded)


def _wider(rel: float, match_tol: float, outcome: str = "takes their mean") -> str:
    """The way out of a refusal for legs or hips that differ by ``rel`` of the leg's
    size: the tolerance that takes their mean (unless it is too wide to be one robot)."""
    need = _round_up(rel) if rel > 0 else match_tol
    if need > MAX_MATCH_TOL:
        return (f" (beyond any match_tol, at most {MAX_MATCH_TOL:g}: too different for one "
                f"mean leg)")
    return (f"; match_tol {match_tol:g} allows less: --match-tol {need:g} (match_tol=) "
            f"{outcome}")


def _round_up(x: float) -> float:
    """The smallest of 1, 2 and 5 x 10^k that is at least ``x``."""
    k = math.floor(math.log10(x))
    return next(float(f"{m}e{k + i}") for i in (0, 1) for m in (1, 2, 5)
                if float(f"{m}e{k + i}") >= x)


def check_match_tol(match_tol) -> float:
    """``match_tol`` checked, as a float.

    Parameters
    ----------
    match_tol : float
        How closely the legs must agree, relative to the leg's size.

    Returns
    -------
    float

    Raises
    ------
    ValueError
        Naming the range (0, :data:`MAX_MATCH_TOL`].
    """
    if isinstance(match_tol, bool) or not isinstance(match_tol, (int, float, np.floating)) \
            or not 0 < match_tol <= MAX_MATCH_TOL:
        raise ValueError(f"match_tol must be a number in (0, {MAX_MATCH_TOL:g}] (relative to "
                         f"the leg's size), got {match_tol!r}")
    return float(match_tol)


# ------------------------------------------------------------------ the foot
_FOOT_WORDS = ("foot", "toe", "sole", "contact", "ankle")
#: below a foot that hangs by a locked joint (an ankle), the frame that marks the sole
_SOLE_WORDS = ("sole", "contact")


def _foot_point(rd: _Reader, last: _Frame, foot, n=None, leg=()) -> tuple:
    """(foot point in the torso frame, where it came from, the foot link or None).
    ``n``: the plane's normal (torso frame), which locked joints below an ankle are the
    leg's own (turning in the plane: a spring, a tarsus, a toe held fixed); ``leg``: the
    leg's joint names (for the refusal)."""
    if foot is not None:
        f = np.asarray(foot, dtype=float).ravel()
        return last.p + last.R @ f, "foot= argument", None
    cands = [(j, f) for j, f in rd.fixed_descendants(last) if j.parent == last.name]
    if len(cands) > 1:
        named = [c for c in cands if any(w in c[1].name.lower() for w in _FOOT_WORDS)]
        soles = [c for c in named if any(w in c[1].name.lower() for w in _SOLE_WORDS)]
        cands = named if len(named) == 1 else soles if len(soles) == 1 else cands
    if len(cands) != 1:
        what = "no child link or fixed frame" if not cands else \
            f"{len(cands)} fixed children ({', '.join(repr(c[1].name) for c in cands)})"
        chain = f" (the leg's joints: {' -> '.join(leg)})" if leg else ""
        rd.fail(f"no foot: the last leg link {last.name!r}{chain} has {what}; give the foot "
                f"point in its frame (foot=(x, y, z), or 'biped robot import FILE --foot "
                f"X Y Z --out robot.toml'), or lock the joint above it if that is an ankle "
                f"(--lock NAME, lock=)")
    j, f = cands[0]
    if j.name not in rd.locked:
        return f.p, f"link {f.name!r}", f.name
    soles = [g for _, g in rd.fixed_descendants(f)
             if any(w in g.name.lower() for w in _SOLE_WORDS)]
    if len(soles) == 1:
        return soles[0].p, f"link {soles[0].name!r} (below the locked joint {j.name!r})", \
            soles[0].name
    if n is not None:
        j, f = _lowest_in_plane(rd, j, f, n)
    rd.notes.append(f"the foot point is the origin of the locked joint {j.name!r} (where "
                    f"{f.name!r} hangs from {j.parent!r}: an ankle, not a sole): the model's "
                    f"foot is the point that touches the ground; with no single fixed frame "
                    f"below it named like a sole or contact, give that point with --foot X Y Z "
                    f"(foot=) in the frame of {last.name!r}, or its distance beyond the ankle "
                    f"along the shin with --foot-beyond D (foot_beyond=)")
    return f.p, f"link {f.name!r} (the locked joint {j.name!r})", f.name


def _lowest_in_plane(rd: _Reader, j, f: _Frame, n) -> tuple:
    """Down a chain of locked joints that turn in the plane (about n: the leg's own
    joints held fixed, as a spring, a tarsus and a toe below a knee), the last one and
    its child frame: the ankle; a locked joint off the plane (an ankle roll) ends it."""
    while True:
        below = [(k, g) for k, g in rd.fixed_descendants(f) if k.parent == f.name
                 and k.name in rd.locked and _parallel(g.R @ rd.unit_axis(k), n)]
        if len(below) != 1:
            return j, f
        j, f = below[0]


def _beyond(rd: _Reader, chain, foot: tuple, d: float, plane) -> tuple:
    """The foot moved ``d`` beyond its point along the last link's line in the plane."""
    p, where, name = foot
    line = plane.flat(p - chain[-1][1].p)
    if not np.linalg.norm(line) > rd.tol:
        rd.fail(f"foot_beyond: the foot point is at the joint {chain[-1][0].name!r}: the last "
                f"link has no line to extend")
    rd.notes.append(f"the foot is {d:g} m beyond {where}, along the line from "
                    f"{chain[-1][0].name!r} (foot_beyond)")
    return p + d * line / np.linalg.norm(line), f"{where} + {d:g} m", name


def _check_foot(foot):
    if foot is not None:
        f = np.asarray(foot, dtype=float).ravel()
        if f.shape != (3,) or not np.all(np.isfinite(f)):
            raise ValueError(f"foot must be 3 finite numbers (x, y, z in m), got {foot!r}")
