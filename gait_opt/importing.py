"""Gaits from other tools: sampled nodes or published virtual constraints brought to the
toolkit's representation and made an exact orbit of the robot given.

1. Nodes (:mod:`gait_opt.nodes`; virtual constraints are first turned into the nodes of
   their hybrid zero dynamics' periodic orbit, :mod:`gait_opt.hzd_orbit`).
2. Fit: q_a^d(t) as a Bezier polynomial in s = t / T (least squares on the values, T dq
   and, when given, T^2 ddq / 10 at the nodes), the lowest degree from 6 to
   :data:`MAX_DEGREE` that meets the nodes within :data:`FIT_TOL` rad (else the best);
   x0 = (q_u, dq_u) of the first node, T its span.  The fit errors are reported.
3. The fitted gait integrates q_u^d by the unactuated row of eq. (1) from x0
   (docs/theory.md).  Its orbit residual (the impact and relabelling of the state at T
   against the state at 0, and z_sw(T)) must be at most ``tol``; otherwise the
   trajectory is not close to an orbit of this robot and is refused (the message gives
   the residual and the likely cause).
4. Polish (:func:`gait_opt.polish.close_orbit`): minimum-norm Newton on the gait's own
   parameters to an exact periodic orbit at the data's speed.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from math import comb
from pathlib import Path

import numpy as np

from biped_casadi.results import Result

from .gait import Gait
from .hzd_orbit import BezierConstraints, constraints_from_dict, hzd_nodes
from .nodes import (ANGLES, Nodes, check_units, nodes_from_arrays, read_nodes,
                    relative_angles)
from .options import GaitOptions, require_model
from .polish import close_orbit
from .urdf_angles import read_urdf_csv, urdf_nodes

__all__ = ["GaitImport", "GaitImportError", "import_gait", "fit_bezier", "IMPORT_TOL",
           "MAX_IMPORT_TOL", "FIT_TOL", "MAX_DEGREE"]

#: the fitted gait's orbit residual (rad, rad/s, m) beyond which an import is refused
IMPORT_TOL = 0.05
#: the largest tolerance taken: a residual of a radian, a rad/s or a metre (more than a
#: step) is not close to an orbit, and beyond it data of another robot passed (RABBIT's
#: own gait against RABBIT without its rotor inertia misses by 5.7, and the polish then
#: made it an orbit of that other robot)
MAX_IMPORT_TOL = 1.0
#: rad: a Bezier degree whose fit meets every node within this is enough
FIT_TOL = 1e-6
#: the highest Bezier degree tried
MAX_DEGREE = 20


class GaitImportError(ValueError):
    """A trajectory that is not (close to) an orbit of the robot given, or a bad input."""


@dataclass
class GaitImport(Result):
    """An imported gait and what the import did to the data.

    ``success`` means the gait is an exact periodic orbit of the robot (status
    'imported').

    Parameters
    ----------
    gait : Gait
        The imported, polished gait.
    status : str
        'imported'.
    source : str
        Where the data came from.
    kind : str
        'nodes' or 'virtual_constraints'.
    n_nodes : int
        Nodes fitted.
    bezier_degree : int
        Degree of the fitted q_a^d(s).
    fit_error_q, fit_error_dq : float
        max ``|fit - data|`` at the nodes, rad and rad/s.
    data_impact_residual : float
        The impact and relabelling of the last node against the first (rad, rad/s):
        the data alone through this robot's impact map.
    unactuated_drift : float
        max ``|q_u^d - q_u|`` at the nodes of the fitted gait (q_u integrated by this
        robot's unactuated row), rad.
    orbit_residual_before, orbit_residual_after : float
        The fitted gait's and the polished gait's orbit residual.
    parameter_change : float
        max change of the Bezier coefficients, x0 and T in the polish.
    T, step_length, speed : float
        s, m, m/s of the polished gait.
    peak_torque, max_friction_ratio, impact_friction_ratio, min_swing_height : float
        N m, ratios and m (the swing foot's lowest point inside the step).
    violations : list
        The default gait constraints the gait violates (name, amount): reported, not
        enforced.
    info : dict
        For virtual constraints: their orbit's ``w_plus``, ``invariance_residual`` and
        ``delta_zero_squared``.
    message : str
        A summary.
    """

    gait: object = field(repr=False, metadata={"dict": False})
    status: str = "imported"
    source: str = ""
    kind: str = "nodes"
    n_nodes: int = 0
    bezier_degree: int = 0
    fit_error_q: float = math.nan
    fit_error_dq: float = math.nan
    data_impact_residual: float = math.nan
    unactuated_drift: float = math.nan
    orbit_residual_before: float = math.nan
    orbit_residual_after: float = math.nan
    parameter_change: float = math.nan
    T: float = math.nan
    step_length: float = math.nan
    speed: float = math.nan
    peak_torque: float = math.nan
    max_friction_ratio: float = math.nan
    impact_friction_ratio: float = math.nan
    min_swing_height: float = math.nan
    violations: list = field(default_factory=list)
    info: dict = field(default_factory=dict)
    message: str = ""

    SUCCESS = ("imported",)


# ------------------------------------------------------------------ the fit
def _bernstein(M: int, s) -> np.ndarray:
    s = np.asarray(s, dtype=float)[:, None]
    k = np.arange(M + 1)[None, :]
    c = np.array([comb(M, j) for j in range(M + 1)], dtype=float)[None, :]
    return c * s**k * (1 - s)**(M - k)


def _bases(M: int, s):
    """B, dB/ds, d2B/ds2 at s: (N, M + 1) each."""
    B = _bernstein(M, s)
    d1 = np.zeros_like(B)
    b1 = _bernstein(M - 1, s)
    d1[:, :-1] -= M * b1
    d1[:, 1:] += M * b1
    d2 = np.zeros_like(B)
    b2 = _bernstein(M - 2, s)
    f = M * (M - 1)
    d2[:, :-2] += f * b2
    d2[:, 1:-1] -= 2 * f * b2
    d2[:, 2:] += f * b2
    return B, d1, d2


def fit_bezier(nodes: Nodes, degree: int) -> tuple:
    """Bezier polynomial of q_a over s = (t - t_0) / T through the end states.

    The two first and two last coefficients make q_a and dq_a equal to the first and
    the last node's (the states of the impact); the others are least squares on the
    values, T dq_a and (when given) T^2 ddq_a / 10 at every node.

    Parameters
    ----------
    nodes : Nodes
        The step (rows 2..n of q are the actuated joints).
    degree : int
        M >= 4.

    Returns
    -------
    tuple
        (alpha (nu, M + 1), max error in q_a (rad), max error in dq_a (rad/s)).
    """
    M = degree
    T = nodes.t[-1] - nodes.t[0]
    s = (nodes.t - nodes.t[0]) / T
    B, d1, d2 = _bases(M, s)
    qa, dqa = nodes.q[1:], nodes.dq[1:]
    fixed = [0, 1, M - 1, M]
    ends = np.stack([qa[:, 0], qa[:, 0] + T * dqa[:, 0] / M, qa[:, -1] - T * dqa[:, -1] / M,
                     qa[:, -1]])                                   # (4, nu)
    free = list(range(2, M - 1))
    rows, rhs = [B, d1], [qa.T, T * dqa.T]
    if nodes.ddq is not None:
        rows.append(0.1 * d2)
        rhs.append(0.1 * T**2 * nodes.ddq[1:].T)
    A, R = np.vstack(rows), np.vstack(rhs)
    coef = np.zeros((M + 1, qa.shape[0]))
    coef[fixed] = ends
    coef[free] = np.linalg.lstsq(A[:, free], R - A[:, fixed] @ ends, rcond=None)[0]
    alpha = coef.T
    eq = float(np.max(np.abs(B @ coef - qa.T)))
    edq = float(np.max(np.abs(d1 @ coef / T - dqa.T)))
    return alpha, eq, edq


def _best_fit(nodes: Nodes, degree):
    if degree is not None:
        if isinstance(degree, bool) or not isinstance(degree, int) or not 4 <= degree <= 20:
            raise GaitImportError(f"bezier_degree must be an integer from 4 to 20, got {degree!r}")
        return (degree,) + fit_bezier(nodes, degree)
    fits = []
    for M in range(6, MAX_DEGREE + 1):
        if M - 3 > 2 * nodes.n:
            break
        fits.append((M,) + fit_bezier(nodes, M))
        if fits[-1][2] <= FIT_TOL:
            return fits[-1]
    low = min(f[2] for f in fits)
    return next(f for f in fits if f[2] <= 1.5 * low)


# ------------------------------------------------------------------ the import
def _nodes_of(model, source, angles: str, where: str, stance=None, tol: float = IMPORT_TOL):
    """(Nodes in relative angles, kind, info) of any accepted source."""
    if angles not in ANGLES + ("urdf",):
        raise GaitImportError(f"angles must be one of {ANGLES + ('urdf',)}, got {angles!r}")
    if (stance is not None) != (angles == "urdf"):
        raise GaitImportError("stance names the stance leg's hip joint of a step in URDF "
                              "angles: give it with angles='urdf' (and only then)")
    if angles == "urdf":
        if isinstance(source, (str, Path)):
            nodes, info = read_urdf_csv(source, model, stance, tol)
        elif isinstance(source, dict):
            nodes, info = urdf_nodes(model, source, stance, where, tol)
        else:
            raise GaitImportError(f"source: a step in URDF angles is a CSV file or a dict of "
                                  f"columns, got {type(source).__name__}")
        return nodes, "nodes", info
    info = {}
    if isinstance(source, (str, Path)):
        source = read_nodes(source)                 # its size checked below, naming the robot
    if isinstance(source, dict) and "bezier" in source:
        source = constraints_from_dict(source, model.nq, where)
    if isinstance(source, BezierConstraints):
        nodes, info = hzd_nodes(model, source)
        return nodes, "virtual_constraints", info
    if isinstance(source, dict):
        missing = [k for k in ("t", "q", "dq") if k not in source]
        if missing:
            raise GaitImportError(f"{where}: missing {', '.join(missing)}")
        source = nodes_from_arrays(source["t"], source["q"], source["dq"], source.get("ddq"),
                                   None, where)
    if not isinstance(source, Nodes):
        raise GaitImportError(f"source must be a file name, a Nodes, a dict of arrays or "
                              f"BezierConstraints, got {type(source).__name__}")
    if source.nq != model.nq:
        raise GaitImportError(f"{where}: {source.nq} coordinates per node, the robot "
                              f"{model.params.name} has {model.nq}: a step of another robot? "
                              f"(give its robot: import_gait's model, on the command line "
                              f"--robot)")
    # a Nodes made by hand gets the checks of arrays (NaN, shapes, increasing times)
    source = dataclasses.replace(
        nodes_from_arrays(source.t, np.transpose(source.q), np.transpose(source.dq),
                          None if source.ddq is None else np.transpose(source.ddq), model.nq,
                          where),
        source=source.source)
    symbol = "phi" if angles == "absolute" else "q"
    names = [f"{symbol}{i}" for i in range(1, source.nq + 1)]
    check_units(source.t, source.q, source.dq, names, where)
    return (relative_angles(source) if angles == "absolute" else source), "nodes", info


def _diagnostics(model, nodes: Nodes, gait: Gait) -> dict:
    qp, dqp = (np.array(v).ravel() for v in model.impact(nodes.q[:, -1], nodes.dq[:, -1]))
    data = max(float(np.max(np.abs(qp - nodes.q[:, 0]))), float(np.max(np.abs(dqp - nodes.dq[:, 0]))))
    z = abs(float(model.swing_foot(nodes.q[:, -1])[1]))
    try:
        drift = float(np.max(np.abs(gait.states(nodes.t - nodes.t[0])[0] - nodes.q[0])))
    except ValueError:
        drift = math.inf
    return dict(data_impact=data, z_end=z, drift=drift)


def _convention_hint(angles: str) -> str:
    return ("another stance leg (--stance)? angles in another convention?" if angles == "urdf"
            else "another coordinate convention? angles='absolute'")


def _cause(d: dict, fit_q: float, angles: str) -> str:
    """The likely reason a trajectory is not an orbit of the robot."""
    other = {"relative": "another coordinate convention (absolute link angles? --angles "
                         "absolute)",
             "urdf": "another stance leg (--stance), or angles in another convention"
             }.get(angles, "another coordinate convention")
    if fit_q > 1e-2:
        return (f"the Bezier fit misses the nodes by {fit_q:.2g} rad (more nodes, or a "
                f"smoother trajectory?)")
    if d["z_end"] > 1e-3:
        return (f"the swing foot is {d['z_end']:.2g} m off the ground at the last node (one "
                f"step must end at the impact), or {other}")
    if d["data_impact"] >= d["drift"]:
        return (f"this robot's impact map does not take the last node to the first (off by "
                f"{d['data_impact']:.2g}): another robot model (rotor inertia, masses, "
                f"lengths), or {other}")
    return (f"the data do not follow this robot's unactuated dynamics (q1 drifts by "
            f"{d['drift']:.2g} rad over the step): another robot model (masses, inertias, "
            f"lengths, rotor inertia), or {other}")


def import_gait(model, source, *, angles: str = "relative", stance=None,
                bezier_degree: int | None = None, tol: float = IMPORT_TOL,
                options: GaitOptions | None = None) -> GaitImport:
    """A gait from another tool, fitted and made an exact orbit of ``model`` (module doc).

    Parameters
    ----------
    model : BipedModel
        The robot the gait is for.
    source : str, Path, Nodes, dict or BezierConstraints
        A file (CSV, NPZ or JSON of nodes, or JSON with ``virtual_constraints``: see
        :mod:`gait_opt.nodes` and :func:`gait_opt.hzd_orbit.constraints_from_dict`), nodes,
        a dict of arrays ``t``, ``q``, ``dq`` (``ddq``), or virtual constraints.
    angles : {'relative', 'absolute', 'urdf'}
        The nodes' coordinates: the toolkit's relative joint angles, absolute link
        angles phi (converted), or the robot's own URDF joint angles and pitch (a CSV
        or a dict of columns, :mod:`gait_opt.urdf_angles`; the robot needs its URDF map).
    stance : str, optional
        With ``angles='urdf'``: the stance leg's hip joint, as the URDF names it.
    bezier_degree : int, optional
        Degree of q_a^d(s) (4 to 20); default chosen by the fit (module docstring).
    tol : float
        The largest orbit residual of the fitted gait (before the polish) accepted
        (positive, at most :data:`MAX_IMPORT_TOL`).
    options : GaitOptions, optional
        Recorded with the gait (its constraints are reported, not enforced); the speed
        and Bezier degree are the import's.

    Returns
    -------
    GaitImport
        The gait and the figures of the import.

    Raises
    ------
    GaitImportError
        (a ValueError) One line: bad input, or not close to an orbit of ``model`` (the
        residual and the likely cause).
    """
    require_model(model)
    where = str(source) if isinstance(source, (str, Path)) else "gait"
    if not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol > 0):
        raise GaitImportError(f"tol must be a positive number, got {tol!r}")
    if tol > MAX_IMPORT_TOL:
        raise GaitImportError(f"tol must be at most {MAX_IMPORT_TOL:g} (rad, rad/s, m: a "
                              f"larger residual is not close to an orbit), got {tol!r}")
    try:
        nodes, kind, info = _nodes_of(model, source, angles, where, stance, tol)
    except GaitImportError:
        raise
    except ValueError as e:
        raise GaitImportError(str(e)) from None
    M, alpha, fit_q, fit_dq = _best_fit(nodes, bezier_degree)
    T = float(nodes.t[-1] - nodes.t[0])
    length = float(model.swing_foot(nodes.q[:, -1])[0])
    if not length > 0:
        raise GaitImportError(f"{where}: the swing foot ends {length:.3g} m from the stance "
                              f"foot at the last node: a step must end in front of it "
                              f"({_convention_hint(angles)})")
    opts = (options or GaitOptions()).replace(speed=length / T, bezier_degree=M)
    fitted = Gait(model, opts.for_model(model), alpha, [nodes.q[0, 0], nodes.dq[0, 0]], T,
                  solver_stats=dict(imported_from=nodes.source, kind=kind))
    before = fitted.orbit_residual()["worst"]
    diag = _diagnostics(model, nodes, fitted)
    if not before <= tol:
        raise GaitImportError(
            f"{where}: not an orbit of {model.params.name}: the fitted gait misses the "
            f"periodic orbit by {before:.2g} (rad, rad/s, m; tolerance {tol:g}); likely "
            f"cause: {_cause(diag, fit_q, angles)}")
    closed = close_orbit(fitted)
    if not closed.success:
        raise GaitImportError(f"{where}: the orbit could not be closed ({closed.message}); "
                              f"likely cause: {_cause(diag, fit_q, angles)}")
    return _result(closed, nodes, kind, info, M, fit_q, fit_dq, before, diag, where)


def _result(closed, nodes, kind, info, M, fit_q, fit_dq, before, diag, where) -> GaitImport:
    g = closed.gait
    c = g.check()
    after = g.orbit_residual()["worst"]
    fig = dict(fit_error_q=fit_q, fit_error_dq=fit_dq, orbit_residual_before=before,
               orbit_residual_after=after, parameter_change=closed.parameter_change,
               data_impact_residual=diag["data_impact"], unactuated_drift=diag["drift"],
               bezier_degree=M, n_nodes=nodes.n)
    g.solver_stats.update(dict(fig, polish_iterations=closed.iterations,
                               **{k: v for k, v in info.items()}))
    return GaitImport(
        gait=g, source=where, kind=kind, T=g.T, step_length=g.step_length, speed=g.speed,
        peak_torque=c["max_abs_torque"], max_friction_ratio=c["max_friction_ratio"],
        impact_friction_ratio=c["impact_friction_ratio"],
        min_swing_height=c["min_swing_height_inside"], violations=g.violations(c), info=info,
        message=(f"{kind} from {where}: Bezier degree {M}, fit error {fit_q:.2e} rad / "
                 f"{fit_dq:.2e} rad/s; orbit residual {before:.2e} -> {after:.2e} "
                 f"({closed.iterations} Newton iteration(s), parameters moved by at most "
                 f"{closed.parameter_change:.2e})"), **fig)
