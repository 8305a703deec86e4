"""The running controller as self-contained C99 code, as the walking controllers are
exported (:mod:`biped_casadi.control.export`).

The law of a :class:`~biped_casadi.control.running.RunningController` is, per phase, a
CasADi Function of (q, dq, t): stance on the stance coordinates (q, dq), flight on the
extended ones (qe, dqe) = ((q, x, z), rates) of the leg that pushed off, t the time since
the phase began.  Both are generated as C by CasADi's code generator from the
controller's own Functions (``stance_law`` and ``flight_law``, the ones the MuJoCo loop
and the stride map call, followed by :meth:`RunningController.applied`: the torques
clipped at the limit when the controller saturates), with a small hand-written wrapper
(:data:`RUNNING_HEADER`):

``int biped_running_sizes(int *nq, int *nu, int *nqe)``
    the sizes of q, of u and of the extended qe;
``int biped_running_torque(int phase, double t, const double *q, const double *dq,
double *u)``
    the torques of phase 0 (stance: q, dq of nq each) or 1 (flight: qe, dqe of nqe each)
    at time t since the phase began.

The gains Kp, Kd, the output's column M1, the law and the saturation are baked into the
code, as in the walking export: an export is one controller, and the generated
arithmetic is the Python law's (other gains: export again, about a second).  The
reference is the gait's collocated polynomials, valid for any t (before 0 and past the
phase's end they continue: :class:`~biped_casadi.control.running.PhaseReference`).
Return codes (:data:`RUNNING_RETURN_CODES`): 0 ok, 2 an unknown phase, 3 an input or a
torque not finite; ``u`` is written in every case (NaN for code 2 and for a non-finite
input).  Work arrays are static: no allocation anywhere, one caller at a time.

:func:`exported_running_law` builds the Functions and constants from a controller,
:func:`running_c_sources` the files' text;
:func:`~biped_casadi.control.export_folder.staged_export` writes them into a folder, all or
nothing.  See docs/howto/export.md ("The running controller").
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .export import MARKER
from .export_urdf import ALL_FINITE_C, c_array as _array, c_number, casadi_c, comment_safe
from .running import RunningController

__all__ = ["ExportedRunningLaw", "exported_running_law", "running_c_sources",
           "running_digest", "running_info", "RUNNING_HEADER", "RUNNING_WRAPPER",
           "RUNNING_GENERATED", "RUNNING_LIBRARY", "RUNNING_INFO", "RUNNING_RETURN_CODES",
           "PHASES"]

#: the files of a running export (the header, the wrapper, CasADi's generated law)
RUNNING_HEADER, RUNNING_WRAPPER, RUNNING_GENERATED = ("biped_running.h", "biped_running.c",
                                                      "biped_running_law.c")
#: the shared library the README's build line makes
RUNNING_LIBRARY = "libbiped_running.so"
#: what the export is of (robot, gait digest, law and gains), as JSON
RUNNING_INFO = "controller.json"
#: what biped_running_torque returns
RUNNING_RETURN_CODES = {0: "ok", 2: "unknown_phase", 3: "not_finite"}
#: the phases, by their number in the C interface
PHASES = ("stance", "flight")
_num = c_number


@dataclass
class ExportedRunningLaw:
    """A running controller's law as CasADi Functions ready for code generation.

    Parameters
    ----------
    nq, nu, nqe : int
        Sizes of q, of u and of the flight's extended qe.
    stance : casadi.Function
        ``biped_running_stance(q, dq, t) -> u``, the torques the robot receives.
    flight : casadi.Function
        ``biped_running_flight(qe, dqe, t) -> u``.
    controller : dict
        ``law``, ``Kp``, ``Kd``, ``M1``, ``saturate``, ``torque_limit``.
    robot : str
        The robot's name.
    gait_digest : str
        :func:`running_digest` of the gait (what the reference is made of).
    T_stance, T_flight : float
        The gait's phase durations, s.
    example_states : dict
        ``stance`` (K, 1 + 2 nq) and ``flight`` (K, 1 + 2 nqe): rows (t, q, dq) on the
        reference, for the example's timing loop.
    """
    nq: int
    nu: int
    nqe: int
    stance: ca.Function = field(repr=False)
    flight: ca.Function = field(repr=False)
    controller: dict
    robot: str
    gait_digest: str
    T_stance: float
    T_flight: float
    example_states: dict = field(repr=False)


def running_digest(gait) -> str:
    """SHA-256 of what a running gait's reference is made of.

    The phase durations and the collocated states and torques, as float64 bytes: two
    gaits with the same digest give the same controller at the same gains.

    Parameters
    ----------
    gait : RunningGait
        The gait (or an object with its fields).

    Returns
    -------
    str
        Hex digest.
    """
    h = hashlib.sha256()
    for name in ("T_stance", "T_flight", "x_stance", "u_stance", "x_flight", "u_flight"):
        a = np.ascontiguousarray(np.asarray(getattr(gait, name), np.float64))
        h.update(name.encode() + str(a.shape).encode() + a.tobytes())
    return h.hexdigest()


def _examples(ctrl: RunningController, n: int = 16) -> dict:
    """n collocated states of each phase with their times (rows t, q, dq)."""
    g, out = ctrl.gait, {}
    for phase in PHASES:
        X = np.asarray(getattr(g, f"x_{phase}"), float)
        T = float(getattr(g, f"T_{phase}"))
        k = np.linspace(0, X.shape[1] - 1, n).round().astype(int)
        out[phase] = np.column_stack([T * k / (X.shape[1] - 1), X[:, k].T])
    return out


def exported_running_law(controller: RunningController) -> ExportedRunningLaw:
    """The law of a running controller as the Functions and constants of an export.

    Parameters
    ----------
    controller : RunningController
        The controller (its gait, law, gains and saturation).

    Returns
    -------
    ExportedRunningLaw

    Raises
    ------
    ValueError
        Naming ``controller`` when it is not a RunningController.
    """
    if not isinstance(controller, RunningController):
        raise ValueError("controller: exported_running_law takes a RunningController "
                         f"(biped_casadi.control.running), got {type(controller).__name__}")
    c, model = controller, controller.model
    nqe = c.fl.ne
    g = c.gait
    return ExportedRunningLaw(
        nq=model.nq, nu=model.nu, nqe=nqe, stance=c.applied_law("stance", "biped_running_stance"),
        flight=c.applied_law("flight", "biped_running_flight"),
        controller=dict(law=c.law, Kp=c.Kp.tolist(), Kd=c.Kd.tolist(), M1=c.M1.tolist(),
                        saturate=c.saturate, torque_limit=c.torque_limit),
        robot=model.params.name, gait_digest=running_digest(g),
        T_stance=float(g.T_stance), T_flight=float(g.T_flight), example_states=_examples(c))


# ======================================================================= C text
def _vector(v) -> str:
    return "[" + ", ".join(_num(x) for x in v) + "]"


def _provenance_lines(law: ExportedRunningLaw, provenance: dict) -> list:
    c = law.controller
    lines = [f"robot: {law.robot} (nq = {law.nq}, nu = {law.nu}, nqe = {law.nqe})"]
    lines += [f"{k}: {v}" for k, v in provenance.items()]
    lines.append(f"running gait digest (sha256 of its durations, states and torques): "
                 f"{law.gait_digest}")
    lines.append(f"phases: stance T = {_num(law.T_stance)} s, flight T = {_num(law.T_flight)} s")
    lines.append("controller: tracking of the running gait, outputs v = [M1, I] q, law "
                 + ("feedforward + PD (Kp N m/rad, Kd N m s/rad)" if c["law"] == "pd" else
                    "computed torque on the outputs (Kp 1/s^2, Kd 1/s)"))
    lines.append(f"Kp = {_vector(c['Kp'])}, Kd = {_vector(c['Kd'])}, M1 = {_vector(c['M1'])}")
    U = c["torque_limit"]
    limit = _num(U) if np.ndim(U) == 0 else \
        f"({', '.join(_num(v) for v in U)}) (u1 .. u{law.nu}, each joint's)"
    lines.append(f"torques clipped at +-{limit} N m" if c["saturate"] else
                 f"torques not clipped (the robot's limit: {limit} N m)")
    return lines


def _header(law: ExportedRunningLaw, provenance: dict) -> str:
    info = comment_safe("\n".join(f" *   {line}" for line in _provenance_lines(law, provenance)))
    return f"""{MARKER}: running (generated; do not edit) */
#ifndef BIPED_RUNNING_H
#define BIPED_RUNNING_H
/*
 * The exported running controller:
{info}
 *
 * Stance (phase 0): q, dq the SPEC coordinates (relative joint angles, the stance leg
 * first), {law.nq} each, rad and rad/s.  Flight (phase 1): the extended qe = (q, x, z), dqe,
 * {law.nqe} each: q read with the leg that pushed off as the stance leg, (x, z) the point of
 * its foot relative to where it left the ground, m.  u: torques on q2..q{law.nq}, N m.
 * t: time since the phase began, s (any finite t: the reference's polynomials continue
 * before 0 and past the phase's end).  After a landing relabel the legs (q+ = E q-)
 * and restart t at 0 in stance.
 * Return codes: 0 ok, 2 unknown phase, 3 not finite (an input, or a torque).  u is
 * written in every case (NaN for 2 and for a non-finite input).  Work arrays are static:
 * one caller at a time.
 */
#ifdef __cplusplus
extern "C" {{
#endif

#define BIPED_RUNNING_STANCE 0
#define BIPED_RUNNING_FLIGHT 1
#define BIPED_RUNNING_OK 0
#define BIPED_RUNNING_UNKNOWN_PHASE 2
#define BIPED_RUNNING_NOT_FINITE 3
/* the gait's phase durations, s */
#define BIPED_RUNNING_T_STANCE {_num(law.T_stance)}
#define BIPED_RUNNING_T_FLIGHT {_num(law.T_flight)}

/* sizes: configuration nq, torques nu, the flight's extended configuration nqe */
int biped_running_sizes(int *nq, int *nu, int *nqe);
/* torques u[nu] of phase BIPED_RUNNING_STANCE (q, dq: nq each) or BIPED_RUNNING_FLIGHT
   (qe, dqe: nqe each) at time t since the phase began */
int biped_running_torque(int phase, double t, const double *q, const double *dq, double *u);

#ifdef __cplusplus
}}
#endif
#endif
"""


def _wrapper(law: ExportedRunningLaw) -> str:
    fns = (law.stance, law.flight)
    n_arg, n_res, n_iw, n_w = (max(max(v), 1) for v in zip(
        *((f.sz_arg(), f.sz_res(), f.sz_iw(), f.sz_w()) for f in fns)))
    return f"""/* The exported running controller's interface ({RUNNING_HEADER}) around the law
   that CasADi generated in {RUNNING_GENERATED}.  C99, the C library and libm only; static
   work arrays. */
#include <math.h>
#include <stddef.h>
#include "{RUNNING_HEADER}"

#define NQ {law.nq}
#define NU {law.nu}
#define NQE {law.nqe}

/* generated by CasADi ({RUNNING_GENERATED}) */
int biped_running_stance(const double **arg, double **res, int *iw, double *w, int mem);
int biped_running_flight(const double **arg, double **res, int *iw, double *w, int mem);

static const double *work_arg[{n_arg}];
static double *work_res[{n_res}];
static int work_iw[{n_iw}];
static double work_w[{n_w}];

{ALL_FINITE_C}/* every torque NaN, the return code rc */
static int not_defined(double *u, int rc)
{{
    int j;
    for (j = 0; j < NU; ++j) u[j] = NAN;
    return rc;
}}

int biped_running_sizes(int *nq, int *nu, int *nqe)
{{
    if (nq) *nq = NQ;
    if (nu) *nu = NU;
    if (nqe) *nqe = NQE;
    return 0;
}}

int biped_running_torque(int phase, double t, const double *q, const double *dq, double *u)
{{
    int n, rc;
    if (phase == BIPED_RUNNING_STANCE) n = NQ;
    else if (phase == BIPED_RUNNING_FLIGHT) n = NQE;
    else return not_defined(u, BIPED_RUNNING_UNKNOWN_PHASE);
    if (!all_finite(&t, 1) || !all_finite(q, n) || !all_finite(dq, n))
        return not_defined(u, BIPED_RUNNING_NOT_FINITE);
    work_arg[0] = q; work_arg[1] = dq; work_arg[2] = &t;
    work_res[0] = u;
    rc = phase == BIPED_RUNNING_STANCE
        ? biped_running_stance(work_arg, work_res, work_iw, work_w, 0)
        : biped_running_flight(work_arg, work_res, work_iw, work_w, 0);
    if (rc) return not_defined(u, BIPED_RUNNING_NOT_FINITE);
    return all_finite(u, NU) ? BIPED_RUNNING_OK : BIPED_RUNNING_NOT_FINITE;
}}
"""


def _example(law: ExportedRunningLaw) -> str:
    s, f = law.example_states["stance"], law.example_states["flight"]
    return f"""/* Time the exported running controller: biped_running_torque in a loop over
   {s.shape[0]} states of each phase, alternately.  Build: gcc -O2 -o example/main example/main.c *.c -lm
   (in the export folder). */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "../{RUNNING_HEADER}"

#define K {s.shape[0]}
#define NQ {law.nq}
#define NQE {law.nqe}
#define NU {law.nu}
/* rows: t, q[{law.nq}], dq[{law.nq}] (stance); t, qe[{law.nqe}], dqe[{law.nqe}] (flight) */
{_array("stance_states", s)}{_array("flight_states", f)}
static double now(void)
{{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}}

int main(int argc, char **argv)
{{
    long n = argc > 1 ? atol(argv[1]) : 1000000L, i;
    int nq, nu, nqe, bad = 0;
    double u[NU], sum = 0.0, t0, t1;
    biped_running_sizes(&nq, &nu, &nqe);
    if (nq != NQ || nu != NU || nqe != NQE) return 1;
    t0 = now();
    for (i = 0; i < n; ++i) {{
        const int phase = (int)(i & 1);
        const double *s = phase ? flight_states + ((i / 2) % K) * (1 + 2 * NQE)
                                : stance_states + ((i / 2) % K) * (1 + 2 * NQ);
        const int m = phase ? NQE : NQ;
        bad += biped_running_torque(phase, s[0], s + 1, s + 1 + m, u) != 0;
        sum += u[0];
    }}
    t1 = now();
    printf("biped_running_torque: %.4f us per call (%ld calls, %d non-zero returns, "
           "checksum %.6e)\\n", 1e6 * (t1 - t0) / (double)n, n, bad, sum);
    return bad != 0;
}}
"""


def _readme(law: ExportedRunningLaw, provenance: dict, timing: str = "") -> str:
    info = "\n".join(f"- {line}" for line in _provenance_lines(law, provenance))
    return f"""# Exported running controller

Generated by `biped export-running`: C99 code that depends on the C standard library and
libm only.

{info}

## Build

    gcc -O2 -shared -fPIC -o {RUNNING_LIBRARY} *.c -lm      # a shared library
    gcc -O2 -c {RUNNING_WRAPPER} {RUNNING_GENERATED}             # objects for a firmware build

`{RUNNING_HEADER}` declares the interface; `{RUNNING_GENERATED}` is the law generated by
CasADi, `{RUNNING_WRAPPER}` the interface around it (static work arrays, no allocation,
not reentrant: one caller at a time). `example/main.c` times the law in a loop:

    gcc -O2 -o example/main example/main.c *.c -lm && ./example/main 1000000
{timing}
## Call

    int nq, nu, nqe;
    biped_running_sizes(&nq, &nu, &nqe);                       /* {law.nq}, {law.nu}, {law.nqe} */
    rc = biped_running_torque(BIPED_RUNNING_STANCE, t, q, dq, u);   /* in stance */
    rc = biped_running_torque(BIPED_RUNNING_FLIGHT, t, qe, dqe, u); /* in flight */

- Stance: `q`, `dq` ({law.nq} each), SPEC coordinates, relative joint angles with the
  stance leg first (q1 the stance leg's absolute angle from the vertical), rad and rad/s.
- Flight: `qe`, `dqe` ({law.nqe} each), the extended coordinates (q, x, z): q read with the
  leg that pushed off as the stance leg, (x, z) its foot's point relative to where it
  left the ground, m.
- `t`: time since the phase began, s; restart it at 0 at the takeoff and at the landing
  (after the landing, relabel the legs: q+ = E q-).  That is the default flight clock;
  with the stance's clock continued (`biped running --flight-clock stride`) give the
  flight the time since landing less {law.T_stance:.6g} s (below 0 when the stance
  ended early). The gait's phases last
  {law.T_stance:.6g} s (stance) and {law.T_flight:.6g} s (flight); the reference continues
  its polynomials past them.
- `u` ({law.nu}): torques on q2..q{law.nq}, N m.
- Return codes: 0 ok, 2 unknown phase, 3 not finite (an input or a torque). `u` is
  written in every case; do not apply it when the code is not 0.
- The gains, M1 and the law are part of the code: export again for other gains.
"""


def running_c_sources(law: ExportedRunningLaw, provenance: dict | None = None,
                      timing: str = "") -> dict:
    """The files of a running export: name (relative to the folder) -> text.

    Parameters
    ----------
    law : ExportedRunningLaw
        From :func:`exported_running_law`.
    provenance : dict, optional
        Further lines for the header's comments (e.g. the gait file and its checksum).
    timing : str
        A measured time per call for the README (empty: none).

    Returns
    -------
    dict
        :data:`RUNNING_HEADER`, :data:`RUNNING_WRAPPER`, :data:`RUNNING_GENERATED`,
        :data:`RUNNING_INFO` (:func:`running_info`), ``README.md`` and ``example/main.c``.

    Raises
    ------
    TypeError
        When ``law`` is not an ExportedRunningLaw.
    """
    if not isinstance(law, ExportedRunningLaw):
        raise TypeError("law: an ExportedRunningLaw is needed (exported_running_law("
                        f"controller)), got {type(law).__name__}")
    provenance = dict(provenance or {})
    return {RUNNING_HEADER: _header(law, provenance), RUNNING_WRAPPER: _wrapper(law),
            RUNNING_GENERATED: casadi_c(RUNNING_GENERATED, [law.stance, law.flight]),
            RUNNING_INFO: json.dumps(running_info(law), indent=1) + "\n",
            "README.md": _readme(law, provenance, timing), "example/main.c": _example(law)}


def running_info(law: ExportedRunningLaw) -> dict:
    """What an export is of: what a loaded library is checked against.

    Parameters
    ----------
    law : ExportedRunningLaw
        From :func:`exported_running_law`.

    Returns
    -------
    dict
        ``kind`` ('running'), ``robot``, ``nq``, ``nu``, ``nqe``, ``gait_digest`` and
        ``controller`` (law, gains, M1, saturation, torque limit).
    """
    return dict(kind="running", robot=law.robot, nq=law.nq, nu=law.nu, nqe=law.nqe,
                gait_digest=law.gait_digest, controller=law.controller)
