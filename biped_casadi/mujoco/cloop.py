"""The common MuJoCo steps of a walk run in C (:class:`~biped_casadi.mujoco.walk.MujocoLoop`).

A step of the Python loop (``_Run.control``, ``mj_step``, ``_Run.advance``) costs about
as much Python as MuJoCo's step itself.  Here a small C function, compiled once per
machine into the cache folder's ``compiled/``, runs those steps one after the other: it
reads MuJoCo's state in the toolkit's coordinates, calls the exported law's
``biped_torque`` (its function pointer), writes ``ctrl``, calls ``mj_step`` (MuJoCo's own
function, from the library the ``mujoco`` package has loaded) and keeps the step's
accounts (slip, travel, peak torque, clipping, the feet's lowest point, the log).  It hands back to Python, before
touching anything of the step, wherever the walk's logic has more to do than that: the
Poincaré section, a law's refusal, a state that is not finite, a full log, and after
MuJoCo's step a fall (the torso's lean judged from the robot's ``torso_upright`` as the
Python loop judges it), the lift-off, a swing-foot contact, a scuff-zone change, the
horizon.  Python then does that step exactly as the Python loop does and resumes.
MuJoCo's fatal errors inside the C function come back as the ``mujoco.FatalError`` that
``mujoco.mj_step`` raises (a thread-local log handler, as the Python bindings install);
its warnings go where they go from Python.

Every number is computed by the same floating-point operations in the same order as the
Python loop: the code is compiled without contraction into FMA (``-ffp-contract=off``)
or other reassociation, and the two matrix products (``A @ angles``, ``G @ u``) add in
the order of OpenBLAS's ``dgemv`` kernel (four-wide lanes summed (l0 + l2) + (l1 + l3),
the tail after, onto y = +0).  That order depends on the BLAS numpy uses and the CPU, so
each matrix is checked against ``numpy.dot`` on random vectors once per process; a
matrix whose products differ, a law without C code, a matrix entry other than 0 or +-1,
or no C compiler leave the walk to the Python loop.
"""
from __future__ import annotations

import ctypes
import hashlib
import math
import os
import subprocess
from pathlib import Path

import numpy as np

from ..control.compiled import CompiledController, find_c_compiler
from ..numerics import cached_library

__all__ = ["DRIVERS", "c_driver_problem", "walk_differences"]

#: how a loop's steps are driven: the C function when it can ('auto'), always ('c'), or
#: the Python loop ('python')
DRIVERS = ("auto", "c", "python")

#: what the C function returns: steps done (the budget), Python's turn for a whole step
#: or for the end of one (after MuJoCo's step), or MuJoCo's error
DONE, PY_STEP, PY_ADVANCE, MUJOCO_ERROR = 0, 1, 2, 3
#: MuJoCo steps per call at most (Python gets control back for Ctrl-C now and then)
BUDGET = 100_000
#: the lengths of the products the C dot product handles (OpenBLAS's dgemv_t, one block)
MAX_DOT = 7

_P, _D, _I, _L = ctypes.c_void_p, ctypes.c_double, ctypes.c_int, ctypes.c_longlong
#: the C struct's fields (in this order), the one definition for C and ctypes
FIELDS = [
    ("m", _P), ("d", _P), ("step", _P), ("law", _P), ("set_tls", _P), ("get_global", _P),
    ("A0", _P), ("A1", _P), ("G0", _P), ("G1", _P),
    ("q0", _P), ("q1", _P), ("dq0", _P), ("dq1", _P), ("p", _P), ("u", _P),
    ("log_t", _P), ("log_qpos", _P), ("log_qvel", _P), ("log_stance", _P), ("log_u", _P),
    ("dt", _D), ("T", _D), ("U", _D), ("r", _D), ("t_sec", _D), ("fall_height", _D),
    ("half_pi", _D), ("zone", _D), ("upright", _D), ("pi", _D), ("two_pi", _D),
    ("t0", _D), ("qu_prev", _D), ("dqu_prev", _D), ("peak", _D), ("z_old", _D),
    ("slip", _D), ("travel", _D), ("x_prev", _D), ("phi_prev", _D), ("z_min", _D),
    ("kmax", _L), ("k", _L), ("clipped", _L), ("airborne", _L), ("log_k", _L),
    ("log_cap", _L),
    ("nq", _I), ("na", _I), ("nu", _I), ("nc", _I), ("foot_a", _I), ("foot_b", _I),
    ("ignore_scuff", _I), ("logging", _I), ("stance", _I), ("slot", _I),
    ("section_none", _I), ("lifted", _I), ("q_slot", _I), ("q_old_slot", _I),
    ("error", ctypes.c_char * 2048),
]
_CTYPE = {_P: "void *", _D: "double", _I: "int", _L: "long long"}


def _declaration(name: str, t) -> str:
    if isinstance(t, type) and issubclass(t, ctypes.Array):
        return f"    char {name}[{t._length_}];"
    return f"    {_CTYPE[t]} {name};"


class _State(ctypes.Structure):
    _fields_ = FIELDS


_SOURCE = r"""
#include <math.h>
#include <setjmp.h>
#include <stdio.h>
#include <string.h>
#include <mujoco/mujoco.h>

typedef struct {
%(fields)s
} cloop_t;

typedef int (*law_fn)(double, const double *, const double *, const double *, double *);
typedef void (*step_fn)(const mjModel *, mjData *);
typedef mjfLogHandler (*set_tls_fn)(mjfLogHandler);
typedef mjfLogHandler (*get_global_fn)(void);

/* MuJoCo's errors inside a call come back here (as the Python bindings do it: a
   thread-local log handler and a longjmp), its other messages go to the global handler */
static __thread cloop_t *current;
static __thread jmp_buf recovery;

static void on_message(const mjLogMessage *msg)
{
    if (msg->level == mjLOG_ERROR && current) {
        if (msg->body && msg->body[0])
            snprintf(current->error, sizeof current->error, "%%s\n%%s", msg->subject, msg->body);
        else
            snprintf(current->error, sizeof current->error, "%%s", msg->subject);
        longjmp(recovery, 1);
    }
    if (current)
        ((get_global_fn)current->get_global)()(msg);
}

/* a . x as OpenBLAS's dgemv_t adds it: the first (n & ~3) terms in four lanes from +0,
   the lanes summed (l0 + l2) + (l1 + l3) onto y = +0, then the 1 to 3 terms left */
static double dot(const double *a, const double *x, int n)
{
    double y = 0.0;
    int b = n & ~3, i;
    if (b) {
        double l0 = 0.0, l1 = 0.0, l2 = 0.0, l3 = 0.0;
        for (i = 0; i < b; i += 4) {
            l0 += a[i] * x[i];
            l1 += a[i + 1] * x[i + 1];
            l2 += a[i + 2] * x[i + 2];
            l3 += a[i + 3] * x[i + 3];
        }
        y += (l0 + l2) + (l1 + l3);
    }
    switch (n & 3) {
    case 3: y += a[b] * x[b] + a[b + 1] * x[b + 1] + a[b + 2] * x[b + 2]; break;
    case 2: y += a[b] * x[b] + a[b + 1] * x[b + 1]; break;
    case 1: y += a[b] * x[b]; break;
    }
    return y;
}

/* y = M x for an (rows, n) row-major M */
void cloop_product(const double *M, const double *x, double *y, int rows, int n)
{
    int j;
    for (j = 0; j < rows; j++)
        y[j] = dot(M + (long)j * n, x, n);
}

long long cloop_version(void) { return (long long)mjVERSION_HEADER; }

static int steps(cloop_t *s, long long budget) __attribute__((noinline));

int cloop_run(cloop_t *s, long long budget)
{
    set_tls_fn set_tls = (set_tls_fn)s->set_tls;
    mjfLogHandler volatile before = set_tls(on_message);
    int volatile event = 3;
    current = s;
    s->error[0] = 0;
    if (setjmp(recovery) == 0)
        event = steps(s, budget);
    current = NULL;
    set_tls(before);
    return event;
}

static int steps(cloop_t *s, long long budget)
{
    mjModel *m = (mjModel *)s->m;
    mjData *d = (mjData *)s->d;
    law_fn law = (law_fn)s->law;
    step_fn step = (step_fn)s->step;
    const int nq = s->nq, na = s->na, nu = s->nu, nc = s->nc, nmj = (int)m->nq;
    const int feet[2] = {s->foot_a, s->foot_b};
    const double dt = s->dt;
    double *u = (double *)s->u;
    long long n;
    int i;
    for (n = 0; n < budget; n++) {
        const int st = s->stance, sw = 1 - st, slot = 1 - s->slot;
        const double tau = (double)s->k * dt - s->t0;
        const double *A = (const double *)(st ? s->A1 : s->A0);
        const double *G = (const double *)(st ? s->G1 : s->G0);
        double *q = (double *)(slot ? s->q1 : s->q0), *dq = (double *)(slot ? s->dq1 : s->dq0);
        const double *angles = d->qpos + 2, *rates = d->qvel + 2;
        double umax, mx, mn, neg;
        int rc;
        if (s->section_none && tau >= s->t_sec)
            return 1;                                   /* the Poincare section */
        if (s->logging && s->log_k == s->log_cap)
            return 1;                                   /* the log grows */
        for (i = 0; i < na; i++)
            if (!isfinite(angles[i]) || !isfinite(rates[i]))
                return 1;
        /* control: the toolkit's state, the law, the torques */
        for (i = 0; i < nq; i++) {
            q[i] = dot(A + (long)i * na, angles, na);
            dq[i] = dot(A + (long)i * na, rates, na);
        }
        rc = law(tau, q, dq, (const double *)s->p, u);
        if (rc)
            return 1;                                   /* the law refuses */
        s->slot = slot;
        s->q_slot = slot;
        s->qu_prev = q[0];
        s->dqu_prev = dq[0];
        mx = mn = u[0];                                 /* max(max(u), -min(u)) */
        for (i = 1; i < nu; i++) {
            if (u[i] > mx) mx = u[i];
            if (u[i] < mn) mn = u[i];
        }
        neg = -mn;
        umax = neg > mx ? neg : mx;
        if (umax > s->peak)
            s->peak = umax;
        if (umax > s->U)
            s->clipped += 1;
        for (i = 0; i < nc; i++)
            d->ctrl[i] = dot(G + (long)i * nu, u, nu);
        if (s->logging) {
            long long r = s->log_k;
            ((double *)s->log_t)[r] = (double)s->k * dt;
            memcpy((double *)s->log_qpos + r * nmj, d->qpos, sizeof(double) * nmj);
            memcpy((double *)s->log_qvel + r * nmj, d->qvel, sizeof(double) * nmj);
            ((signed char *)s->log_stance)[r] = (signed char)st;
            memcpy((double *)s->log_u + r * nu, u, sizeof(double) * nu);
            s->log_k = r + 1;
        }
        step(m, d);
        s->k += 1;
        /* advance: Python's when anything but the stance foot's accounts happens */
        {
            int touch[2] = {0, 0}, c;
            const double *xpos = d->geom_xpos, *qp = d->qpos;
            double z_now, xs, phs, lean;
            for (c = 0; c < d->ncon; c++) {
                int g0 = d->contact[c].geom[0], g1 = d->contact[c].geom[1];
                if (g0 == feet[0] || g1 == feet[0]) touch[0] = 1;
                if (g0 == feet[1] || g1 == feet[1]) touch[1] = 1;
            }
            lean = qp[2];                               /* the torso's lean from upright */
            if (s->upright != 0.0) {
                lean = qp[2] - s->upright;
                lean = lean - s->two_pi * floor((lean + s->pi) / s->two_pi);
            }
            if (!(qp[1] - s->r > s->fall_height && -s->half_pi < lean && lean < s->half_pi))
                return 2;                               /* a fall, or not finite */
            if (!s->lifted) {
                double t = (double)(s->k - 1) * dt - s->t0;
                if (!touch[sw] || t > 0.5 * s->T)
                    return 2;                           /* lift-off, or scuffed */
            } else if (touch[sw]) {
                return 2;                               /* a touchdown, or scuffed */
            } else if (s->ignore_scuff && m->geom_contype[feet[sw]] == 0
                       && xpos[3 * feet[sw]] - xpos[3 * feet[st]] > s->zone) {
                return 2;                               /* out of the scuff zone */
            }
            if ((double)s->k * dt - s->t0 > (double)s->kmax * dt)
                return 2;                               /* the horizon */
            z_now = xpos[3 * feet[sw] + 2];
            xs = xpos[3 * feet[st]];
            phs = q[0];
            s->z_old = z_now;
            s->q_old_slot = slot;
            if (touch[st] && s->lifted) {
                s->slip += (xs - s->x_prev) - s->r * (phs - s->phi_prev);
            } else {
                s->travel += xs - s->x_prev;
                s->airborne += s->lifted;
            }
            s->x_prev = xs;
            s->phi_prev = phs;
            if (xpos[3 * feet[0] + 2] < s->z_min) s->z_min = xpos[3 * feet[0] + 2];
            if (xpos[3 * feet[1] + 2] < s->z_min) s->z_min = xpos[3 * feet[1] + 2];
        }
    }
    return 0;
}
"""


def _source() -> str:
    return _SOURCE % {"fields": "\n".join(_declaration(name, t) for name, t in FIELDS)}


_FLAGS = ("-O2", "-fno-fast-math", "-ffp-contract=off", "-fPIC", "-shared")
_LIB: dict = {}
_CHECKED: dict = {}


def _mujoco_paths():
    """(the include folder, the loaded libmujoco) of the ``mujoco`` package."""
    import mujoco
    root = Path(mujoco.__file__).parent
    libs = sorted(root.glob("libmujoco.so*"))
    if not (root / "include" / "mujoco" / "mujoco.h").is_file() or not libs:
        raise OSError("the mujoco package has no headers or libmujoco here")
    return root / "include", libs[0], mujoco.__version__


def _library():
    """The compiled C loop and MuJoCo's ``mj_step`` (cached per process), or a reason."""
    if "lib" in _LIB:
        return _LIB["lib"]
    try:
        cc = find_c_compiler()
        if cc is None:
            raise OSError("no C compiler")
        include, libmujoco, version = _mujoco_paths()
        src = _source()
        key = hashlib.sha256("\0".join([src, " ".join(cc), " ".join(_FLAGS), version,
                                        (include / "mujoco" / "mjdata.h").read_text(),
                                        (include / "mujoco" / "mjmodel.h").read_text()])
                             .encode()).hexdigest()[:24]

        def build(tmp, out):
            c = os.path.join(tmp, "cloop.c")
            Path(c).write_text(src, encoding="utf-8")
            subprocess.run([*cc, *_FLAGS, f"-I{include}", c, "-o", out, "-lm"], check=True,
                           capture_output=True)

        lib = ctypes.CDLL(str(cached_library(f"mujoco-cloop-{key}.so", build)))
        mj = ctypes.CDLL(str(libmujoco))                # the one the package has loaded
        lib.cloop_run.argtypes, lib.cloop_run.restype = [ctypes.c_void_p, _L], ctypes.c_int
        lib.cloop_product.argtypes = [_P, _P, _P, _I, _I]
        lib.cloop_product.restype = None
        lib.cloop_version.restype = _L
        mj.mj_version.restype = ctypes.c_int
        if lib.cloop_version() != mj.mj_version():
            raise OSError("the loaded libmujoco is not the headers' version")
        result = (lib, tuple(ctypes.cast(getattr(mj, f), ctypes.c_void_p).value for f in
                             ("mj_step", "_mjPRIVATE_setTlsLogHandler",
                              "_mjPRIVATE_getGlobalLogHandler")), "")
    except (OSError, subprocess.CalledProcessError, AttributeError) as e:
        result = (None, None, f"the C loop is not available ({str(e).splitlines()[0]})")
    _LIB["lib"] = result
    return result


def _same_products(lib, M: np.ndarray) -> bool:
    """Whether the C product equals ``numpy.dot(M, x, out=y)`` bit for bit, ``x`` a view
    at an offset like ``qpos[2:]`` (checked once per process per matrix)."""
    key = (M.shape, M.tobytes())
    if key in _CHECKED:
        return _CHECKED[key]
    rows, n = M.shape
    ok = n <= MAX_DOT and bool(np.all(np.isin(M, (-1.0, 0.0, 1.0))))
    rng = np.random.default_rng(20260)
    trials = 1500 if ok else 0
    X = rng.normal(0.0, 1.0, (trials, n)) * 10.0 ** rng.integers(-9, 9, (trials, n))
    X[::7, 0], X[3::7, n - 1] = 0.0, -0.0
    X[::11] = np.round(X[::11], 0)                  # sums that vanish: the sign of zero
    buf, y, yc = np.zeros(n + 3), np.zeros(rows), np.zeros(rows)
    x, dot, product = buf[2:2 + n], np.dot, lib.cloop_product
    for row in X:
        x[:] = row
        dot(M, x, out=y)
        product(M.ctypes.data, x.ctypes.data, yc.ctypes.data, rows, n)
        if y.tobytes() != yc.tobytes():
            ok = False
            break
    _CHECKED[key] = ok
    return ok


def c_driver_problem(loop) -> str:
    """Why a loop's steps cannot run in C (empty when they can).

    Parameters
    ----------
    loop : MujocoLoop
        Its law (compiled C is needed) and its coordinate maps (each checked against
        numpy's product once per process).

    Returns
    -------
    str
        The reason, or ``''`` when the C function can drive its steps.
    """
    if type(loop.law) is not CompiledController:       # a subclass may call it otherwise
        return "the law is not the compiled C law"
    if not isinstance(loop.torque_limit, float):       # the C steps count against one limit
        return "the joints' torque limits differ"
    lib, _, why = _library()
    if lib is None:
        return why
    lay = loop.layout
    for M in (*lay.A, *lay.G):
        M = np.ascontiguousarray(M, float)
        if not _same_products(lib, M):
            return "the C products differ from numpy's here"
    return ""


class Driver:
    """The C function bound to one run's buffers (``_Run``): its state in a C struct,
    copied in before each call and back after."""

    def __init__(self, run):
        lib, (mj_step, set_tls, get_global), _ = _library()
        self.lib, self.run_c = lib, lib.cloop_run
        loop, s = run.loop, _State()
        self.s, self.ref = s, ctypes.byref(s)
        self.A = [np.ascontiguousarray(a, float) for a in run.A]
        self.G = [np.ascontiguousarray(g, float) for g in run.G]
        law = loop.law
        s.m, s.d, s.step = loop.m._address, loop.d._address, mj_step
        s.set_tls, s.get_global = set_tls, get_global
        s.law = ctypes.cast(law._lib.biped_torque, ctypes.c_void_p).value
        s.A0, s.A1 = self.A[0].ctypes.data, self.A[1].ctypes.data
        s.G0, s.G1 = self.G[0].ctypes.data, self.G[1].ctypes.data
        (q0, q1), (dq0, dq1) = run.qs, run.dqs
        s.q0, s.q1, s.dq0, s.dq1 = (a.ctypes.data for a in (q0, q1, dq0, dq1))
        s.p = run.p.ctypes.data if run.p.size else law._ptr["p"]
        s.u = law._ptr["u"]
        s.dt, s.T, s.U, s.r, s.t_sec = run.dt, run.T, run.U, run.r, run.t_sec
        s.fall_height, s.half_pi, s.zone = run.fall_height, math.pi / 2, float(run.zone)
        s.upright, s.pi, s.two_pi = run.upright, math.pi, 2.0 * math.pi
        s.kmax, s.nq, s.na = run.kmax, len(q0), self.A[0].shape[1]
        s.nu, s.nc = self.G[0].shape[1], self.G[0].shape[0]
        s.foot_a, s.foot_b = run.feet
        s.ignore_scuff, s.logging = int(bool(run.ignore_scuff)), int(bool(run.logging))

    def __call__(self, run, budget: int = BUDGET) -> int:
        """Run steps until Python's turn: DONE, PY_STEP or PY_ADVANCE (MuJoCo's fatal
        error: ``mujoco.FatalError``, as ``mujoco.mj_step`` raises it)."""
        s, log = self.s, run.log
        if run.logging:
            s.log_t, s.log_qpos, s.log_qvel = (log.t.ctypes.data, log.qpos.ctypes.data,
                                               log.qvel.ctypes.data)
            s.log_stance, s.log_u = log.stance.ctypes.data, log.u.ctypes.data
            s.log_k, s.log_cap = log.k, log.t.size
        s.t0, s.qu_prev, s.dqu_prev, s.peak = run.t0, run.qu_prev, run.dqu_prev, run.peak
        s.z_old, s.slip, s.travel = run.z_old, run.slip, run.travel
        s.x_prev, s.phi_prev, s.z_min = run.x_prev, run.phi_prev, run.z_min
        s.k, s.clipped, s.airborne = run.k, run.clipped, run.airborne
        s.stance, s.slot, s.lifted = run.stance, run.slot, int(run.lifted)
        s.section_none = int(run.section is None)
        s.q_slot = s.q_old_slot = -1
        event = self.run_c(self.ref, budget)
        if event == MUJOCO_ERROR:                 # what mujoco.mj_step raises
            import mujoco
            raise mujoco.FatalError(s.error.decode(errors="replace"))
        if s.q_slot >= 0:                         # a step's control done in C
            i = s.q_slot
            run.slot, run.q, run.dq = i, run.qs[i], run.dqs[i]
            run.qu_prev, run.dqu_prev, run.peak, run.clipped = (s.qu_prev, s.dqu_prev,
                                                                 s.peak, s.clipped)
            run.k = s.k
            if run.logging:
                log.k = s.log_k
        if s.q_old_slot >= 0:                     # and its advance
            i = s.q_old_slot
            run.q_old, run.dq_old, run.z_old = run.qs[i], run.dqs[i], s.z_old
            run.slip, run.travel, run.airborne = s.slip, s.travel, s.airborne
            run.x_prev, run.phi_prev, run.z_min = s.x_prev, s.phi_prev, s.z_min
        return event


def _bits(x):
    """A value with every float as its bytes (NaN, -0.0 and inf compare as they are)."""
    if isinstance(x, np.ndarray):
        return (x.dtype.str, x.shape, x.tobytes())
    if isinstance(x, (float, np.floating)):
        return ("f", np.float64(x).tobytes(), type(x).__name__ == "float")
    if isinstance(x, (list, tuple)):
        return tuple(_bits(v) for v in x)
    if isinstance(x, dict):
        return tuple((k, _bits(v)) for k, v in x.items())
    if hasattr(x, "__dataclass_fields__"):
        return tuple((k, _bits(getattr(x, k))) for k in x.__dataclass_fields__)
    return (type(x).__name__, x)


def walk_differences(a, b, ignore=("wall_time",)) -> list:
    """The fields in which two walks differ, floats and arrays compared bit for bit.

    Parameters
    ----------
    a, b : MujocoWalk
        Two walks (the same walk driven in C and in Python, say).
    ignore : tuple of str
        Fields not compared (the wall time by default).

    Returns
    -------
    list of str
        The differing fields' names (and a step's index for ``steps``), empty when the
        walks are the same.
    """
    out = []
    for name in a.__dataclass_fields__:
        if name in ignore:
            continue
        x, y = getattr(a, name), getattr(b, name)
        if name == "steps" and len(x) == len(y):
            out += [f"steps[{i}].{k}" for i, (s, t) in enumerate(zip(x, y))
                    for k in s.__dataclass_fields__
                    if _bits(getattr(s, k)) != _bits(getattr(t, k))]
        elif _bits(x) != _bits(y):
            out.append(name)
    return out
