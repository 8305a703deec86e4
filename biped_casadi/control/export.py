"""The closed-loop controllers as self-contained C99 code for a robot's real-time loop.

The control law of a :class:`~biped_casadi.control.TimeVaryingController` (outputs
v = [M1, I] q, the stride-to-stride correction v_c of eq. 17, the torques of eq. 12-13)
or of a :class:`~biped_casadi.control.VirtualConstraintController` is rebuilt as one
CasADi Function of (q, dq, tau, the step state) and generated as C by CasADi's code
generator; a small hand-written wrapper gives it the three functions of the header
(:data:`HEADER`):

``int biped_sizes(int *nq, int *nu, int *nstate)``
    the sizes of q, of u and of the controller state;
``int biped_step_start(const double *q, const double *dq, double *state)``
    the step constants, at start-up and just after every impact;
``int biped_torque(double tau, const double *q, const double *dq, const double *state,
double *u)``
    the torques at time tau since the step started;

and one more, ``biped_outputs`` (the outputs y, their rates and the decoupling
denominator of eq. 24).  Every function returns :data:`RETURN_CODES` (0 when all is well).

The time-varying law needs the reference's unactuated coordinate q_u^d(tau), which a gait
defines as the solution of the unactuated row of eq. (1) (:mod:`biped_casadi.control.
time_varying`); the C code reads it from a table of the gait's own interpolation nodes
(:meth:`~biped_casadi.control.Reference.state_nodes`) with the same quintic Hermite
interpolant, so the compiled law is the Python law :meth:`TimeVaryingController.torque`.
Work arrays are static: no allocation anywhere, one caller at a time.

:func:`exported_law` builds the Functions and constants from a controller,
:func:`c_sources` the files' text; :mod:`biped_casadi.control.export_folder` writes them
into a folder, all or nothing.  See docs/theory.md (the controller) and docs/howto/export.md.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..numerics import quintic_hermite_interval
from .design import Design
from .export_urdf import (ALL_FINITE_C, LEG_ORDER, URDF_START_C, c_array as _array, c_number,
                          casadi_c, comment_safe, urdf_functions, urdf_header_doc,
                          urdf_readme_doc)
from .saturation import clip_torques
from .time_varying import TimeVaryingController
from .virtual_constraints import VirtualConstraintController

__all__ = ["ExportedLaw", "exported_law", "c_sources", "hermite_state", "HEADER", "WRAPPER",
           "GENERATED", "LIBRARY", "RETURN_CODES", "MARKER", "SINGULAR_FRACTION", "TAU_SLACK",
           "EXPORT_ANGLES"]

#: the coordinates an exported law can take: the toolkit's relative angles, or the robot's
#: own URDF joint angles (:mod:`biped_casadi.control.export_urdf`)
EXPORT_ANGLES = ("relative", "urdf")

#: the files of an export (the header, the wrapper, CasADi's generated law)
HEADER, WRAPPER, GENERATED = "biped_controller.h", "biped_controller.c", "biped_law.c"
#: the shared library the README's build line makes
LIBRARY = "libbiped_controller.so"
#: what the functions return
RETURN_CODES = {0: "ok", 1: "singular", 2: "out_of_range", 3: "not_finite"}
#: tau may exceed the reference's last time by this much (s): the gait's own slack
TAU_SLACK = 1e-12
#: first line of every exported header: marks a folder as an export (may be replaced)
MARKER = "/* biped-casadi controller export"
#: the law counts as singular where the decoupling denominator, times its sign along the
#: reference, is at most this fraction of its largest magnitude there (the simulator's
#: default ``SimulationOptions.singular_tolerance``)
SINGULAR_FRACTION = 0.01


@dataclass
class ExportedLaw:
    """A controller's law as CasADi Functions ready for code generation, and its constants.

    Parameters
    ----------
    kind : str
        'tv' or 'vc'.
    nq, nu, nstate : int
        Sizes of q, of u and of the controller state (the step constants).
    law : casadi.Function
        ``biped_law(q, dq, tau, state, node) -> (u, y, dy, den, in_range)``; ``node`` =
        (t_i, h, y_i, dy_i, ddy_i, y_i+1, dy_i+1, ddy_i+1), the interval of the reference
        state's table around tau (empty without a table).
    start : casadi.Function
        ``biped_start(q, dq) -> (state, go)``; the step cannot start unless go > 0.
    table : dict or None
        The reference state's nodes from t = 0 on: ``t``, ``y``, ``dy``, ``ddy`` (N,),
        and ``t0``, ``h``, ``offset`` (the full grid's first time, its spacing, and the
        index of t = 0 in it), so that the interval is the reference's own.
    tau_max : float
        Largest tau the law accepts, s (inf: tau is not used).
    den_sign, den_scale : float
        Sign and largest magnitude of the decoupling denominator along the reference.
    singular_fraction : float
        The law is singular where den * den_sign <= singular_fraction * den_scale.
    controller : dict
        The controller's ``describe()``.
    robot : str
        The robot's name.
    gait_digest : str
        The reference's ``cache_key`` (digest of what defines it).
    T : float
        Step duration of the reference, s.
    example_states : numpy.ndarray
        (K, 1 + 2 nq + nstate): (tau, q, dq, state) on the reference, for the example
        (in the law's own coordinates).
    angles : str
        'relative' (the toolkit's q) or 'urdf' (pitch and URDF joint angles in, torques
        per URDF joint out; ``state[0]`` the stance leg).
    urdf : UrdfMap or None
        With 'urdf': the robot's joint map.
    motor_side : bool
        With 'urdf': torques divided by each joint's reduction.
    front : casadi.Function or None
        With 'urdf': ``biped_front(x) -> ahead``, which finds the stance leg.
    torque_limit : float, tuple of float or None
        The law's torques are clipped at +-torque_limit, N m (one bound per torque where
        the robot's joints' limits differ) (``saturate``), in the
        model's coordinates before any URDF mapping; None: not clipped.
    """
    kind: str
    nq: int
    nu: int
    nstate: int
    law: ca.Function = field(repr=False)
    start: ca.Function = field(repr=False)
    table: dict | None
    tau_max: float
    den_sign: float
    den_scale: float
    singular_fraction: float
    controller: dict
    robot: str
    gait_digest: str
    T: float
    example_states: np.ndarray = field(repr=False)
    angles: str = "relative"
    urdf: object = field(default=None, repr=False)
    motor_side: bool = False
    front: ca.Function | None = field(default=None, repr=False)
    torque_limit: float | tuple | None = None


def hermite_state(tau, node):
    """The reference state r = (y, dy/dt) at tau from an interval's Hermite nodes (CasADi).

    The interpolant of :meth:`gait_opt.Gait.state`
    (:func:`~biped_casadi.numerics.quintic_hermite_interval`).

    Parameters
    ----------
    tau : casadi.SX
        Time, s.
    node : casadi.SX
        (8,): t_i, h, y_i, dy_i, ddy_i, y_i+1, dy_i+1, ddy_i+1.

    Returns
    -------
    casadi.SX
        (2,): y(tau), dy/dt(tau).
    """
    th = (tau - node[0]) / node[1]
    y, dy, _ = quintic_hermite_interval(th, node[1], *(node[k] for k in range(2, 8)))
    return ca.vertcat(y, dy)


def _state_table(reference) -> dict:
    """The reference state's interpolation nodes from t = 0 to t_max."""
    nodes = reference.state_nodes()
    if nodes is None:
        raise ValueError("controller: its reference has a state but no interpolation nodes "
                         "(Reference.state_nodes) to tabulate in C")
    t, y, dy, ddy = (np.asarray(v, float).ravel() for v in nodes)
    h = float(t[1] - t[0])
    offset = int(np.searchsorted(t, 0.0, side="right")) - 1
    return dict(t=t[offset:], y=y[offset:], dy=dy[offset:], ddy=ddy[offset:], t0=float(t[0]),
                h=h, offset=offset, n_full=int(t.size))


def _law_functions(ctrl, nq, limit=None):
    """(law, start) Functions of the export, with the export's inputs and outputs; the
    torques clipped at +-``limit`` (None: not clipped)."""
    q, dq, tau = ca.SX.sym("q", nq), ca.SX.sym("dq", nq), ca.SX.sym("tau")
    p = ca.SX.sym("state", ctrl.n_par)
    qs, dqs = ca.SX.sym("q", nq), ca.SX.sym("dq", nq)
    _, p0 = ctrl.start(qs, dqs)
    if isinstance(ctrl, TimeVaryingController):
        node = ca.SX.sym("node", 8)
        u, y, dy, den, _, inr = ctrl.law(q, dq, tau, hermite_state(tau, node), p)
        go = ca.SX(1)
    else:
        node = ca.SX.sym("node", 0)
        u, y, dy, den, _, inr = ctrl.law(q, dq, tau, ca.SX(0, 1), p)
        vc = ctrl.constraints
        go = ca.mtimes(ca.DM(vc.c).T, dqs) * float(vc.direction) if ctrl.correction \
            else ca.SX(1)
    if limit is not None:
        u = clip_torques(u, limit)
    law = ca.Function("biped_law", [q, dq, tau, p, node], [u, y, dy, den, inr],
                      ["q", "dq", "tau", "state", "node"], ["u", "y", "dy", "den", "in_range"])
    start = ca.Function("biped_start", [qs, dqs], [p0, go], ["q", "dq"], ["state", "go"])
    return law, start


def exported_law(controller, singular_fraction: float = SINGULAR_FRACTION,
                 angles: str = "relative", motor_side: bool = False, saturate: bool = False,
                 torque_limit: float | None = None) -> ExportedLaw:
    """The law of a controller as the Functions and constants of an export.

    Parameters
    ----------
    controller : Design, TimeVaryingController or VirtualConstraintController
        The controller to export (a :class:`~biped_casadi.Design` on its gait, or its
        controller).
    singular_fraction : float
        The compiled law reports 'singular' where its decoupling denominator (eq. 24 for
        the time-varying law) falls to this fraction of its largest magnitude on the
        reference, or changes sign (default :data:`SINGULAR_FRACTION`).
    angles : {'relative', 'urdf'}
        The law's coordinates: the toolkit's q, or the robot's own URDF joint angles and
        pitch, with torques per URDF joint (the robot needs its URDF map;
        :mod:`biped_casadi.control.export_urdf`).
    motor_side : bool
        With 'urdf': torques divided by each joint's transmission reduction.
    saturate : bool
        Clip the law's torques at +-``torque_limit`` in the C code, as
        ``SimulationOptions(saturate=True)`` clips those the robot receives.
    torque_limit : float, optional
        N m; default the robot's limit.

    Returns
    -------
    ExportedLaw

    Raises
    ------
    ValueError
        Naming ``controller`` for another kind of controller or a design that is
        singular along its own gait (eq. 24), ``singular_fraction`` outside (0, 1),
        ``angles`` unknown or 'urdf' for a robot without a URDF map, ``motor_side``
        without 'urdf', ``saturate`` without a finite positive limit.
    """
    if isinstance(controller, Design):
        controller = controller.controller_for()
    if not isinstance(controller, (TimeVaryingController, VirtualConstraintController)):
        raise ValueError("controller: export takes a TimeVaryingController or a "
                         f"VirtualConstraintController, got {type(controller).__name__}")
    if not (isinstance(singular_fraction, (int, float)) and 0 < singular_fraction < 1):
        raise ValueError(f"singular_fraction must be in (0, 1), got {singular_fraction!r}")
    if angles not in EXPORT_ANGLES:
        raise ValueError(f"angles must be one of {EXPORT_ANGLES}, got {angles!r}")
    if motor_side and angles != "urdf":
        raise ValueError("motor_side: the motor side is that of the URDF's transmissions "
                         "(angles='urdf')")
    model, ref = controller.model, controller.reference
    umap = model.description.urdf
    if angles == "urdf" and umap is None:
        raise ValueError(f"angles: the robot {model.params.name} has no URDF joint map (give "
                         f"the robot as its .urdf file, or a description written by 'biped "
                         f"robot import')")
    limit = model.description.torque_bound if torque_limit is None else float(torque_limit)
    if saturate and not (np.all(np.isfinite(limit)) and np.all(np.greater(limit, 0))):
        raise ValueError(f"saturate: the robot {model.params.name} has no torque limit to clip "
                         f"at (give torque_limit), got {limit!r}")
    rep = controller.singularity()
    if rep.singular:
        raise ValueError(f"controller: the design is singular along its own gait (eq. 24: the "
                         f"decoupling denominator ranges over [{rep.min_value:.4g}, "
                         f"{rep.max_value:.4g}] on the step)")
    law, start = _law_functions(controller, model.nq, limit if saturate else None)
    front = None
    nstate = controller.n_par
    examples = _example_states(controller)
    if angles == "urdf":
        law, start, front = urdf_functions(law, start, model, umap, motor_side)
        nstate += 1
        examples = _urdf_examples(examples, umap, model.nq)
    table = _state_table(ref) if controller.n_ref > 0 else None
    kind = "tv" if isinstance(controller, TimeVaryingController) else "vc"
    return ExportedLaw(
        kind=kind, nq=model.nq, nu=model.nu, nstate=nstate, law=law, start=start,
        table=table, tau_max=float(ref.t_max) if table is not None else math.inf,
        den_sign=1.0 if rep.max_value > 0 else -1.0,
        den_scale=max(abs(rep.min_value), abs(rep.max_value)),
        singular_fraction=float(singular_fraction), controller=controller.describe(),
        robot=model.params.name, gait_digest=str(ref.cache_key), T=float(ref.T),
        example_states=examples, angles=angles, urdf=umap if angles == "urdf" else None,
        motor_side=bool(motor_side), front=front, torque_limit=limit if saturate else None)


def _urdf_examples(rows, umap, nq) -> np.ndarray:
    """The example's states in URDF angles, leg 1 in stance (state[0] = 0)."""
    x, dx = umap.from_model(rows[:, 1:1 + nq].T, rows[:, 1 + nq:1 + 2 * nq].T, LEG_ORDER[0])
    return np.column_stack([rows[:, 0], x.T, dx.T, np.zeros(rows.shape[0]),
                            rows[:, 1 + 2 * nq:]])


def _example_states(ctrl, n: int = 16) -> np.ndarray:
    """n states on the reference (tau, q, dq, state) with the step constants of its
    start, for the example's timing loop."""
    ref = ctrl.reference
    p = ctrl.step_start(ref.q(0.0), ref.dq(0.0)).p
    tau = np.arange(n) * ref.T / n
    q, dq = ref.q(tau), ref.dq(tau)
    return np.column_stack([tau, q.T, dq.T, np.tile(p, (n, 1))])


# ======================================================================= C text
_num = c_number


def _provenance_lines(law: ExportedLaw, provenance: dict) -> list:
    c = law.controller
    lines = [f"robot: {law.robot} (nq = {law.nq}, nu = {law.nu})"]
    if law.angles == "urdf":
        lines.append("coordinates: the URDF's joint angles and the root link's pitch in, "
                     f"torques per URDF joint out ({'motor' if law.motor_side else 'joint'} "
                     "side); state[0] the stance leg")
    lines += [f"{k}: {v}" for k, v in provenance.items()]
    lines.append(f"gait definition digest (sha256): {law.gait_digest}")
    lines.append(f"step duration T = {_num(law.T)} s")
    g = c["gains"]
    if law.kind == "tv":
        lines.append("controller: time-varying outputs v = [M1, I] q, correction v_c (eq. 17), "
                     "torques of eq. 12-13")
        lines.append("M1 = [" + ", ".join(_num(v) for v in c["M1"]) + "]")
        lines.append(f"rejoin = {_num(c['rejoin'])} T")
    else:
        lines.append("controller: virtual constraints H0 q = h_d(theta), theta = c q, fitted "
                     "to the gait" + (", with the phase-based correction" if c["correction"]
                                      else ""))
        lines.append("phase c = [" + ", ".join(_num(v) for v in c["c"]) + "], "
                     f"{c['n_segments']} quintic Bezier segments, fit residual "
                     f"{c['fit_residual']:.3g} rad")
    lines.append(f"gains: Kp = {_num(g['Kp'])}, Kd = {_num(g['Kd'])}, eps = {_num(g['eps'])} s")
    if law.torque_limit is not None:
        U = law.torque_limit
        lines.append(f"torques clipped at +-{_num(U)} N m (the model's joints)" if np.ndim(U) == 0
                     else "torques u1 .. u%d clipped at +-(%s) N m (the model's joints)"
                     % (law.nu, ", ".join(_num(v) for v in U)))
    return lines


def _coordinates_doc(law: ExportedLaw) -> str:
    """The header's paragraph on the inputs, outputs and state."""
    if law.angles == "urdf":
        return urdf_header_doc(law.urdf, law.nu, law.motor_side)
    return f""" * q, dq: SPEC coordinates (relative joint angles, stance leg first: q1 the stance leg's
 * absolute angle, then the stance knee, the stance hip, the swing hip, the swing knee),
 * rad and rad/s; u: torques on q2..q{law.nq}, N m; tau: time since the step started, s."""


def _header(law: ExportedLaw, provenance: dict) -> str:
    info = comment_safe("\n".join(f" *   {line}" for line in _provenance_lines(law, provenance)))
    urdf = law.angles == "urdf"
    start_doc = ("""/* at start-up and just after every impact: fills the controller state, state[0]
   the stance leg (the leg whose foot is in front; returns 2 when the feet are level,
   then name it with biped_step_start_leg); returns 0, or non-zero when the step cannot
   be controlled */
int biped_step_start(const double *q, const double *dq, double *state);
/* the same with the stance leg named: 0 or 1 (see above) */
int biped_step_start_leg(int stance, const double *q, const double *dq, double *state);"""
                 if urdf else """/* at start-up and just after every impact (state already relabelled): fills the
   controller state (the step constants of eq. 17 for the time-varying law, whatever
   the virtual-constraint law needs); returns 0, or non-zero when the step cannot be
   controlled */
int biped_step_start(const double *q, const double *dq, double *state);""")
    return f"""{MARKER} (generated; do not edit) */
#ifndef BIPED_CONTROLLER_H
#define BIPED_CONTROLLER_H
/*
 * The exported controller:
{info}
 *
{_coordinates_doc(law)}
 * Return codes: 0 ok, 1 singular (eq. 24), 2 out of range (tau, or the phase, outside the
 * reference's range{", or state[0] not a leg" if urdf else ""}), 3 not finite.  Outputs are written in every case.  Work arrays are
 * static: one caller at a time.
 */
#ifdef __cplusplus
extern "C" {{
#endif

/* sizes: configuration nq, torques nu, controller state nstate */
int biped_sizes(int *nq, int *nu, int *nstate);
{start_doc}
/* torques u[nu] at time tau since the step started; returns 0, or non-zero when the
   law is singular (eq. 24) or tau lies outside the reference's range */
int biped_torque(double tau, const double *q, const double *dq,
                 const double *state, double *u);

/* extra: the outputs y[nu], their rates dy[nu] and the decoupling denominator den
   (kg m^2; zero where the law is singular) at the same arguments; returns as biped_torque */
int biped_outputs(double tau, const double *q, const double *dq, const double *state,
                  double *y, double *dy, double *den);

#ifdef __cplusplus
}}
#endif
#endif
"""


def _table_text(law: ExportedLaw) -> str:
    t = law.table
    if t is None:
        return "/* no reference-state table: the law does not use tau */\n"
    return ("/* the reference state r = (q_u^d, dq_u^d): the gait's quintic Hermite nodes from "
            "t = 0 */\n"
            f"#define REF_N {t['t'].size}\n"
            f"static const double ref_t0 = {_num(t['t0'])};  /* first node of the full grid */\n"
            f"static const double ref_h = {_num(t['h'])};\n"
            f"static const long ref_offset = {t['offset']}L;  /* index of t = 0 */\n"
            + _array("ref_t", t["t"]) + _array("ref_y", t["y"]) + _array("ref_dy", t["dy"])
            + _array("ref_ddy", t["ddy"]))


_NODE_CODE = """    double node[8];
    double k;
    long i;
    if (!(tau >= 0.0 && tau <= TAU_MAX)) return not_defined(u, y, dy, den);
    k = floor_div(tau - ref_t0, ref_h) - (double)ref_offset;
    i = k < 0.0 ? 0L : (k > (double)(REF_N - 2) ? (long)(REF_N - 2) : (long)k);
    node[0] = ref_t[i]; node[1] = ref_h;
    node[2] = ref_y[i]; node[3] = ref_dy[i]; node[4] = ref_ddy[i];
    node[5] = ref_y[i + 1]; node[6] = ref_dy[i + 1]; node[7] = ref_ddy[i + 1];
    work_arg[4] = node;
"""

_FLOOR_DIV = """/* floor(a / b) exactly as numpy's floor division, which picks the gait's interval */
static double floor_div(double a, double b)
{
    double mod = fmod(a, b), div = (a - mod) / b, fl;
    if (mod != 0.0 && ((b < 0.0) != (mod < 0.0))) div -= 1.0;
    if (div == 0.0) return 0.0;
    fl = floor(div);
    if (div - fl > 0.5) fl += 1.0;
    return fl;
}

"""


_HELPERS = ALL_FINITE_C + """/* tau outside the reference's range: every output NaN, return code 2 */
static int not_defined(double *u, double *y, double *dy, double *den)
{
    int j;
    for (j = 0; j < NU; ++j) {
        if (u) u[j] = NAN;
        if (y) y[j] = NAN;
        if (dy) dy[j] = NAN;
    }
    if (den) *den = NAN;
    return 2;
}

"""


_START_C = """int biped_step_start(const double *q, const double *dq, double *state)
{
    double go = 0.0;
    work_arg[0] = q; work_arg[1] = dq;
    work_res[0] = state; work_res[1] = &go;
    if (biped_start(work_arg, work_res, work_iw, work_w, 0)) return 3;
    if (!all_finite(q, NQ) || !all_finite(dq, NQ)) return 3;
    if (!(go > 0.0)) return 2;
    return all_finite(state, NSTATE) ? 0 : 3;
}
"""


def _wrapper(law: ExportedLaw) -> str:
    sz = lambda f: (f.sz_arg(), f.sz_res(), f.sz_iw(), f.sz_w())  # noqa: E731
    fns = [law.law, law.start] + ([law.front] if law.front is not None else [])
    n_arg, n_res, n_iw, n_w = (max(max(v), 1) for v in zip(*(sz(f) for f in fns)))
    nu, nq, ns = law.nu, law.nq, law.nstate
    tv = law.table is not None
    urdf = law.angles == "urdf"
    declare_front = ("int biped_front(const double **arg, double **res, int *iw, double *w, "
                     "int mem);\n" if urdf else "")
    start_code = URDF_START_C if urdf else _START_C
    leg_check = ("    if (!(state[0] == 0.0 || state[0] == 1.0)) return not_defined(u, y, dy, den);\n"
                 if urdf else "")
    return f"""/* The exported controller's interface (biped_controller.h) around the law that
   CasADi generated in {GENERATED}.  C99, the C library and libm only; static work arrays. */
#include <math.h>
#include <stddef.h>
#include "{HEADER}"

#define NQ {nq}
#define NU {nu}
#define NSTATE {ns}
#define TAU_MAX {_num(law.tau_max + TAU_SLACK)}
#define DEN_SIGN {_num(law.den_sign)}
#define DEN_LIMIT {_num(law.singular_fraction * law.den_scale)}  /* {_num(law.singular_fraction)} of the largest |den| on the reference */

/* generated by CasADi ({GENERATED}) */
int biped_law(const double **arg, double **res, int *iw, double *w, int mem);
int biped_start(const double **arg, double **res, int *iw, double *w, int mem);
{declare_front}
static const double *work_arg[{n_arg}];
static double *work_res[{n_res}];
static int work_iw[{n_iw}];
static double work_w[{n_w}];

{_table_text(law)}
{_FLOOR_DIV if tv else ""}{_HELPERS}int biped_sizes(int *nq, int *nu, int *nstate)
{{
    if (nq) *nq = NQ;
    if (nu) *nu = NU;
    if (nstate) *nstate = NSTATE;
    return 0;
}}

{start_code}
static int evaluate(double tau, const double *q, const double *dq, const double *state,
                    double *u, double *y, double *dy, double *den)
{{
    double in_range = 0.0;
{leg_check}{_NODE_CODE if tv else "    if (!(tau >= 0.0 && tau <= TAU_MAX)) return not_defined(u, y, dy, den);" + chr(10) + "    work_arg[4] = NULL;" + chr(10)}    work_arg[0] = q; work_arg[1] = dq; work_arg[2] = &tau; work_arg[3] = state;
    work_res[0] = u; work_res[1] = y; work_res[2] = dy; work_res[3] = den;
    work_res[4] = &in_range;
    if (biped_law(work_arg, work_res, work_iw, work_w, 0)) return 3;
    if (!(in_range > 0.0)) return 2;
    if (!all_finite(den, 1) || (u != NULL && !all_finite(u, NU))) return 3;
    if (!(*den * DEN_SIGN > DEN_LIMIT)) return 1;
    return 0;
}}

int biped_torque(double tau, const double *q, const double *dq,
                 const double *state, double *u)
{{
    double den = 0.0;
    return evaluate(tau, q, dq, state, u, NULL, NULL, &den);
}}

int biped_outputs(double tau, const double *q, const double *dq, const double *state,
                  double *y, double *dy, double *den)
{{
    double u[NU];
    return evaluate(tau, q, dq, state, u, y, dy, den);
}}
"""


def _generated(law: ExportedLaw) -> str:
    return casadi_c(GENERATED, [law.law, law.start] + ([law.front] if law.front is not None
                                                       else []))


def _example(law: ExportedLaw) -> str:
    nq, ns = law.nq, law.nstate
    # the example's states are read with leg 0 in stance (an export in URDF angles)
    start_call = "biped_step_start_leg(0, " if law.angles == "urdf" else "biped_step_start("
    rows = law.example_states
    return f"""/* Time the exported controller: biped_torque in a loop over {rows.shape[0]} states of the
   reference.  Build: gcc -O2 -o example example/main.c *.c -lm (in the export folder). */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "../{HEADER}"

#define K {rows.shape[0]}
#define NQ {nq}
#define NU {law.nu}
#define NSTATE {max(ns, 1)}
/* rows: tau, q[{nq}], dq[{nq}], state[{ns}] */
{_array("states", rows)}
static double now(void)
{{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}}

int main(int argc, char **argv)
{{
    long n = argc > 1 ? atol(argv[1]) : 1000000L, i;
    int nq, nu, nstate, rc = 0, bad = 0;
    double u[NU], sum = 0.0, t0, t1, state[NSTATE];
    const int w = 1 + 2 * NQ + {ns};
    biped_sizes(&nq, &nu, &nstate);
    if (nq != NQ || nu != NU || nstate != {ns}) return 1;
    t0 = now();
    for (i = 0; i < n; ++i) {{
        const double *s = states + (i % K) * w;
        rc = biped_torque(s[0], s + 1, s + 1 + NQ, s + 1 + 2 * NQ, u);
        bad += rc != 0;
        sum += u[0];
    }}
    t1 = now();
    printf("biped_torque: %.4f us per call (%ld calls, %d non-zero returns, checksum %.6e)\\n",
           1e6 * (t1 - t0) / (double)n, n, bad, sum);
    t0 = now();
    for (i = 0; i < n / 10 + 1; ++i) {{
        const double *s = states + (i % K) * w;
        bad += {start_call}s + 1, s + 1 + NQ, state) != 0;
    }}
    t1 = now();
    printf("biped_step_start: %.4f us per call\\n", 1e6 * (t1 - t0) / (double)(n / 10 + 1));
    return bad != 0;
}}
"""


def _readme_coordinates(law: ExportedLaw, state_doc: str) -> str:
    tv = law.kind == "tv"
    tau = (f"`tau`: time since the step started, s\n  (restart it at 0 at every impact"
           f"{f'; accepted up to {law.tau_max:.6g} s' if tv else ''}).")
    if law.angles != "urdf":
        return f"""- `q`, `dq` ({law.nq} each): SPEC coordinates, relative joint angles with the stance leg
  first (q1 the stance leg's absolute angle from the vertical, then the stance knee, the
  stance hip, the swing hip, the swing knee), rad and rad/s. After an impact relabel the
  legs (q+ = E q-) before calling `biped_step_start`.
- `u` ({law.nu}): torques on q2..q{law.nq}, N m. {tau}
- `state` ({law.nstate}): {state_doc}."""
    return urdf_readme_doc(law.urdf, law.nq, law.nu, law.nstate, law.motor_side, state_doc,
                           tau)


def _readme(law: ExportedLaw, provenance: dict, timing: str = "") -> str:
    info = "\n".join(f"- {line}" for line in _provenance_lines(law, provenance))
    tv = law.kind == "tv"
    state_doc = ("the step constants of eq. 17, (y_i, dy_i) = (M q - v^d(0), M dq - dv^d(0))"
                 if tv else "(theta_i, y_i, dy_i/ds) of the phase-based correction")
    return f"""# Exported controller

Generated by `biped export`: C99 code that depends on the C standard library and libm only.

{info}

## Build

    gcc -O2 -shared -fPIC -o {LIBRARY} *.c -lm      # a shared library
    gcc -O2 -c biped_controller.c biped_law.c       # objects for a firmware build

`{HEADER}` declares the interface; `{GENERATED}` is the law generated by CasADi,
`{WRAPPER}` the interface around it (static work arrays, no allocation, not reentrant:
one caller at a time). `example/main.c` times the law in a loop:

    gcc -O2 -o example/main example/main.c *.c -lm && ./example/main 1000000
{timing}
## Call

    int nq, nu, nstate;
    biped_sizes(&nq, &nu, &nstate);              /* {law.nq}, {law.nu}, {law.nstate} */
    biped_step_start(q, dq, state);              /* at start-up and after every impact */
    rc = biped_torque(tau, q, dq, state, u);     /* every control period */

{_readme_coordinates(law, state_doc)}
- Return codes: 0 ok, 1 singular (the decoupling denominator, eq. 24, below
  {law.singular_fraction:g} of its largest magnitude on the reference, or of the other
  sign), 2 out of range ({"tau outside [0, t_max]" if tv else "the phase theta = c q outside the fitted range"},
  or a step that cannot start), 3 not finite. `u` is written in every case; do not
  apply it when the code is not 0.
- `biped_outputs` gives the outputs y, their rates and the denominator at the same
  arguments.
"""


def c_sources(law: ExportedLaw, provenance: dict | None = None, timing: str = "") -> dict:
    """The files of an export: name (relative to the folder) -> text.

    Parameters
    ----------
    law : ExportedLaw
        From :func:`exported_law`.
    provenance : dict, optional
        Further lines for the header's comments (e.g. the gait file and its checksum).
    timing : str
        A measured time per call for the README (empty: none).

    Returns
    -------
    dict
        :data:`HEADER`, :data:`WRAPPER`, :data:`GENERATED`, ``README.md`` and
        ``example/main.c``.
    """
    if not isinstance(law, ExportedLaw):
        raise TypeError(f"law: an ExportedLaw is needed (exported_law(controller)), got "
                        f"{type(law).__name__}")
    provenance = dict(provenance or {})
    return {HEADER: _header(law, provenance), WRAPPER: _wrapper(law),
            GENERATED: _generated(law), "README.md": _readme(law, provenance, timing),
            "example/main.c": _example(law)}
