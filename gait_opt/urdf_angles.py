"""A step in the robot's own URDF joint angles: read from a CSV into the model's
coordinates, and a gait written back in them.

The CSV (one step, from just after an impact to just before the next; s, rad, rad/s, m,
m/s; one row per node) has the header

    t, pitch, <every URDF leg joint name>, dpitch, d<every joint name>[, x, z, dx, dz]

in any column order: ``pitch`` is the root (torso) link's absolute angle about the
joints' axis, right-handed about it (:mod:`biped_casadi.model.urdf_map`), the joint
columns the URDF's joint angles, the ``d`` columns their rates.  The stance leg is named
by its hip joint.  The optional ``x``, ``z`` (and ``dx``, ``dz``) are the root link's
origin in the world (x forward along n x z, z up): the model pins the stance foot, so
they are not coordinates; they are checked instead: the stance foot they imply must
stay put (within the import's tolerance) -- the test that catches another ``--stance``
or another angle convention before any fit.

The conversion is :meth:`~biped_casadi.model.urdf_map.UrdfMap.to_model` (angles kept
continuous along the step, the first node's in [-pi, pi)).
"""
from __future__ import annotations

import csv
import io
from pathlib import Path

import casadi as ca
import numpy as np

from biped_casadi.files import file_path, read_text_file, write_text_atomic

from .nodes import Nodes, check_units, csv_table, nodes_from_arrays

__all__ = ["urdf_columns", "urdf_nodes", "read_urdf_csv", "gait_table", "write_gait_csv",
           "CSV_ANGLES", "require_urdf_map"]

#: the angle conventions a gait can be written in
CSV_ANGLES = ("relative", "absolute", "urdf")
_BASE = ("x", "z", "dx", "dz")


def require_urdf_map(model, what: str = "--angles urdf"):
    """The model's URDF joint map, or a ValueError saying the robot has none.

    Parameters
    ----------
    model : BipedModel
        The robot.
    what : str
        The option that asked (for the message).

    Returns
    -------
    UrdfMap

    Raises
    ------
    ValueError
        One line when the robot was not read from a URDF.
    """
    m = model.description.urdf
    if m is None:
        raise ValueError(f"{what}: the robot {model.params.name} has no URDF joint map (give "
                         f"the robot as its .urdf file, or a description written by "
                         f"'biped robot import'; a gait file keeps its robot's map)")
    return m


def urdf_columns(urdf_map, base: bool = False) -> list:
    """The CSV header of a step in URDF angles.

    Parameters
    ----------
    urdf_map : UrdfMap
        The robot's joint map.
    base : bool
        With the root link's position and velocity (x, z, dx, dz).

    Returns
    -------
    list of str
    """
    names = list(urdf_map.names)
    return (["t", "pitch"] + names + ["dpitch"] + [f"d{n}" for n in names]
            + (list(_BASE) if base else []))


def _rotate(f, u, angle):
    """(f, u) in the plane (forward, up) turned by ``angle`` right-handed about n."""
    c, s = np.cos(angle), np.sin(angle)
    return f * c + u * s, -f * s + u * c


def _hip_positions(model, q, dq):
    """The hip's position and velocity relative to the stance foot, (2, N) each."""
    qs, dqs = ca.SX.sym("q", model.nq), ca.SX.sym("dq", model.nq)
    hip = model.points(qs)[:, model.hip_index]
    f = ca.Function("hip", [qs, dqs], [hip, ca.jtimes(hip, qs, dqs)])
    P, V = f.map(q.shape[1])(q, dq)
    return np.array(P), np.array(V)


def _root_origin(urdf_map, pitch, dpitch):
    """The root link's origin relative to the hip (and its velocity), (2, N) each."""
    hf, hu = urdf_map.hip
    rf, ru = _rotate(hf, hu, pitch)                # the hip from the origin
    drf, dru = (-hf * np.sin(pitch) + hu * np.cos(pitch)) * dpitch, \
        (-hf * np.cos(pitch) - hu * np.sin(pitch)) * dpitch
    return -np.vstack([rf, ru]), -np.vstack([drf, dru])


def _stance_foot_motion(model, urdf_map, nodes, columns, q, dq) -> tuple:
    """How far (m) and how fast (m/s, None without dx, dz) the stance foot moves over the
    step, by the base columns x, z (dx, dz) of ``nodes`` in URDF angles, read with the
    stance leg of the model's coordinates ``q``, ``dq`` (n, N)."""
    P, V = _hip_positions(model, q, dq)
    o, do = _root_origin(urdf_map, nodes.q[0], nodes.dq[0])
    bx = np.vstack([np.asarray(columns["x"], float), np.asarray(columns["z"], float)])
    spread = float(np.max(np.ptp(bx - o - P, axis=1)))    # world foot = hip_world - hip(q)
    if "dx" not in columns:
        return spread, None
    dbx = np.vstack([np.asarray(columns["dx"], float), np.asarray(columns["dz"], float)])
    return spread, float(np.max(np.abs(dbx - do - V)))


def _moves(spread, speed, tol) -> bool:
    """Whether a stance foot's motion (:func:`_stance_foot_motion`) exceeds ``tol``."""
    return not np.isfinite(spread) or spread > tol or (speed or 0.0) > tol


def urdf_nodes(model, columns: dict, stance, where: str = "gait",
               tol: float = 0.05) -> tuple:
    """Nodes in the model's coordinates from columns in URDF angles.

    Parameters
    ----------
    model : BipedModel
        A robot with a URDF joint map.
    columns : dict
        Column name -> (N,) values (module docstring; ``x``, ``z``, ``dx``, ``dz``
        optional).
    stance : str
        The stance leg's hip joint (URDF name).
    where : str
        Names the source in messages.
    tol : float
        m (m/s): the largest motion of the stance foot the base columns may imply.

    Returns
    -------
    tuple
        (Nodes in the model's relative angles, info dict: ``stance``, and with base
        columns ``stance_foot_spread`` (m) and ``stance_foot_speed`` (m/s)).

    Raises
    ------
    ValueError
        One line: no URDF map, unknown stance joint, missing or unknown columns, values
        that are not numbers, or a stance foot that moves.
    """
    umap = require_urdf_map(model)
    leg = umap.stance_leg(stance)
    stance_name = umap.hips[leg - 1]
    want = urdf_columns(umap)
    have = list(columns)
    missing = [c for c in want if c not in have]
    if missing:
        raise ValueError(f"{where}: missing column(s) {', '.join(missing)} (a step in URDF "
                         f"angles has t, pitch, the joints {', '.join(umap.names)}, dpitch "
                         f"and d + each joint; optionally x, z, dx, dz)")
    unknown = [c for c in have if c not in want and c not in _BASE]
    if unknown:
        raise ValueError(f"{where}: unknown column(s) {', '.join(unknown)} (not a joint of "
                         f"the URDF: {', '.join(umap.names)}; nor pitch, x, z or their rates)")
    base = [c for c in _BASE if c in have]
    if base and set(base) not in ({"x", "z"}, set(_BASE)):
        raise ValueError(f"{where}: base columns {', '.join(base)}: give x and z (and "
                         f"optionally both dx and dz)")
    for c in base:
        if not np.all(np.isfinite(np.asarray(columns[c], dtype=float))):
            raise ValueError(f"{where}: {c} has a NaN or infinite value")
    t = columns["t"]
    x = np.vstack([columns["pitch"]] + [columns[n] for n in umap.names])
    dx = np.vstack([columns["dpitch"]] + [columns[f"d{n}"] for n in umap.names])
    nodes = nodes_from_arrays(t, x.T, dx.T, None, model.nq, where)       # (N, n)
    check_units(nodes.t, nodes.q, nodes.dq, ["pitch"] + list(umap.names), where)
    q, dq = umap.to_model(nodes.q, nodes.dq, leg, continuous=True,
                          centre=model.description.upright_q)
    info = dict(stance=stance_name)
    if base:
        spread, speed = _stance_foot_motion(model, umap, nodes, columns, q, dq)
        info["stance_foot_spread"] = spread
        if speed is not None:
            info["stance_foot_speed"] = speed
        if _moves(spread, speed, tol):
            other = umap.hips[2 - leg]
            o_spread, o_speed = _stance_foot_motion(
                model, umap, nodes, columns, *umap.to_model(
                    nodes.q, nodes.dq, 3 - leg, continuous=True,
                    centre=model.description.upright_q))
            hint = (f"with --stance {other} it moves by {o_spread:.3g} m too: angles in "
                    f"another convention (a URDF other than the data's?)"
                    if _moves(o_spread, o_speed, tol) else
                    f"another stance leg (--stance {other}?), angles in another convention")
            raise ValueError(
                f"{where}: the base columns x, z say the stance foot (leg of {stance_name}) "
                f"moves by {spread:.3g} m during the step"
                + (f" at up to {speed:.3g} m/s" if speed is not None else "")
                + f" (tolerance {tol:g}): {hint}, or not one step on a pinned foot")
    return Nodes(nodes.t, q, dq, None, where), info


def read_urdf_csv(path, model, stance, tol: float = 0.05) -> tuple:
    """Nodes in the model's coordinates from a CSV in URDF angles (module docstring).

    Parameters
    ----------
    path : str or Path
        The ``.csv`` file.
    model : BipedModel
        A robot with a URDF joint map.
    stance : str
        The stance leg's hip joint.
    tol : float
        As :func:`urdf_nodes`.

    Returns
    -------
    tuple
        (Nodes, info) as :func:`urdf_nodes`.

    Raises
    ------
    ValueError
        Naming the file: unreadable, not CSV of numbers, or as :func:`urdf_nodes`.
    """
    path = Path(path)
    where = f"gait file {path}"
    if path.suffix.lower() != ".csv":
        raise ValueError(f"{where}: a step in URDF angles is a CSV file (.csv)")
    umap = model.description.urdf
    columns = ("" if umap is None else f"t, pitch, the joints {', '.join(umap.names)}, dpitch "
               f"and d + each joint; optionally x, z, dx, dz")
    head, a = csv_table(read_text_file(path, "gait file", 50_000_000), where, columns)
    if len(set(head)) != len(head):
        dup = next(c for c in head if head.count(c) > 1)
        raise ValueError(f"{where}: column {dup!r} appears twice in the header")
    return urdf_nodes(model, {h: a[:, i] for i, h in enumerate(head)}, stance, where, tol)


def gait_table(gait, angles: str = "relative", stance=None, n_nodes: int = 101) -> tuple:
    """A gait sampled as the rows of a CSV that :func:`gait_opt.import_gait` reads back.

    Parameters
    ----------
    gait : Gait
        The gait (one step, t from 0 to T).
    angles : {'relative', 'absolute', 'urdf'}
        The toolkit's relative angles (header t, q1..qn, dq1..dqn, ddq1..ddqn), absolute
        link angles phi (the same header), or the URDF's joint angles (header of
        :func:`urdf_columns`, with the root's position x, z, dx, dz; the stance foot at
        the origin).
    stance : str, optional
        For 'urdf': the stance leg's hip joint (default: leg 1's).
    n_nodes : int
        Uniform samples from 0 to T (>= 5).

    Returns
    -------
    tuple
        (header list, (n_nodes, columns) array).

    Raises
    ------
    ValueError
        Naming ``angles``, ``stance`` or ``n_nodes``.
    """
    if angles not in CSV_ANGLES:
        raise ValueError(f"angles must be one of {CSV_ANGLES}, got {angles!r}")
    if isinstance(n_nodes, bool) or not isinstance(n_nodes, int) or not 5 <= n_nodes <= 100_000:
        raise ValueError(f"n_nodes must be an integer from 5 to 100000, got {n_nodes!r}")
    model = gait.model
    t = np.linspace(0.0, gait.T, n_nodes)
    q, dq, ddq = gait.evaluate(t)
    n = model.nq
    if angles != "urdf":
        if angles == "absolute":
            q, dq, ddq = (np.cumsum(a, axis=0) for a in (q, dq, ddq))
        head = (["t"] + [f"q{i}" for i in range(1, n + 1)] + [f"dq{i}" for i in range(1, n + 1)]
                + [f"ddq{i}" for i in range(1, n + 1)])
        return head, np.vstack([t[None], q, dq, ddq]).T
    umap = require_urdf_map(model, "angles='urdf'")
    leg = umap.stance_leg(umap.hips[0] if stance is None else stance)
    x, dx = umap.from_model(q, dq, leg, continuous=True)
    P, V = _hip_positions(model, q, dq)
    o, do = _root_origin(umap, x[0], dx[0])
    return urdf_columns(umap, base=True), np.vstack([t[None], x, dx, P + o, V + do]).T


def write_gait_csv(gait, path, angles: str = "relative", stance=None,
                   n_nodes: int = 101) -> Path:
    """Write a gait as a CSV of nodes (:func:`gait_table`), atomically.

    Parameters
    ----------
    gait : Gait
        The gait.
    path : str or Path
        The ``.csv`` file.
    angles : {'relative', 'absolute', 'urdf'}
        The coordinates.
    stance : str, optional
        For 'urdf': the stance leg's hip joint.
    n_nodes : int
        Uniform samples from 0 to T.

    Returns
    -------
    Path
    """
    head, rows = gait_table(gait, angles, stance, n_nodes)
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerow(head)     # URDF names may hold commas
    text = out.getvalue() + "\n".join(",".join(repr(float(v)) for v in r)
                                      for r in rows) + "\n"
    return write_text_atomic(file_path(path), text)
