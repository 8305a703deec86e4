"""Batch kernels: an SX Function run over many scenarios, four at a time in SIMD lanes.

CasADi's generated C evaluates one scenario per call in scalar double precision, one of
the four double lanes of an AVX2 register.  This module translates an SX Function's
instruction list (its work vector, after CasADi's register allocation) into C on a
four-lane vector type (GCC's vector extensions), each instruction one vector operation,
so four scenarios cost about what one did:

- sines and cosines, the costly instructions, are planned: the sine and the cosine of
  one value share one inline range reduction and polynomial pair (``vsincos``: the
  fdlibm kernels' minimax coefficients, within 1 ulp of libm on the tested range), and
  those of a sum or difference of values whose sines and cosines are known (the model's
  link angles are sums of joint coordinates) come from the addition formulas;
- a call of another Function (a B-spline) runs CasADi's generated C for it lane by lane.

:class:`AccumulatedMap` is the batched form of ``f.mapaccum(K)`` mapped over scenarios,
the pattern of a fixed-step integration: the first inputs of ``f`` are its state, fed
from its first outputs node after node; the other inputs are per scenario (constant
along the nodes), per node (shared by every scenario) or one value for all.  The whole
K-node run of a block of four scenarios happens in C; the scenarios are split over
threads (ctypes releases the GIL).  :func:`kernels` compiles several into one library,
kept in the cache folder by content and CPU (``-march=native``).

IEEE semantics are kept (no ``-ffast-math``: NaN and infinities propagate as in the
scalar code, which the simulators rely on).  Results differ from CasADi's scalar
evaluation by rounding only (fused multiply-adds, the sine and cosine, the addition
formulas): ``tests/test_simd.py`` measures it (1e-13 relative on every operation, the
walkers' verdicts unchanged).

Without a C compiler, on a CPU without AVX2 and FMA, or for an instruction this
translator does not know, :func:`kernels` returns None and the caller keeps CasADi's map.
"""
from __future__ import annotations

import contextlib
import ctypes
import functools
import hashlib
import os
import re
import subprocess
from concurrent.futures import ThreadPoolExecutor

import casadi as ca
import numpy as np

from .files import write_text_atomic
from .numerics import cached_library, note_not_compiled

__all__ = ["AccumulatedMap", "kernels", "available"]

LANES = 4


class _Untranslatable(Exception):
    """A Function this translator has no vector form for (the caller falls back to
    CasADi's own evaluation)."""

_HEADER = r"""
#include <math.h>
typedef double V __attribute__((vector_size(32)));
typedef long long L __attribute__((vector_size(32)));
V _ZGVdN4v_exp(V);
V _ZGVdN4v_log(V);
static const V ZERO = {0.0, 0.0, 0.0, 0.0};
static const V ONE = {1.0, 1.0, 1.0, 1.0};
#define S(c) ((V){c, c, c, c})
#define B(m) ((V)((m) & (L)ONE))
#define SEL(m, a, b) ((V)(((L)(a) & (m)) | ((L)(b) & ~(m))))
/* sine and cosine of four lanes at once, inline (a call would spill every vector
   register): x = q pi/2 + r, |r| <= pi/4, with pi/2 in three parts (exact products for
   |q| < 2^20), then the minimax polynomials of fdlibm's kernels on r, the quadrant by
   swapping and negating.  Lanes beyond 1e5 rad (or infinite) take libm's scalar path. */
static inline __attribute__((always_inline)) void vsincos(V x, V* sn, V* cs) {
    const V big = S(1e5);
    V ax = (V)((L)x & (L)S(0x1.fffffffffffffp+1023));
    L out = ax > big;
    V q = __builtin_ia32_roundpd256(x * S(6.36619772367581382433e-01), 8);
    V r = x - q * S(1.57079632673412561417e+00);
    r = r - q * S(6.07710050630396597660e-11);
    r = r - q * S(2.02226624871116645580e-21);
    V z = r * r, v = z * r;
    V ps = S(8.33333333332248946124e-03) + z * (S(-1.98412698298579493134e-04) + z * (
        S(2.75573137070700676789e-06) + z * (S(-2.50507602534068634195e-08)
        + z * S(1.58969099521155010221e-10))));
    V si = r + v * (S(-1.66666666666666324348e-01) + z * ps);
    V pc = z * (S(4.16666666666666019037e-02) + z * (S(-1.38888888888741095749e-03) + z * (
        S(2.48015872894767294178e-05) + z * (S(-2.75573143513906633035e-07) + z * (
        S(2.08757232129817482790e-09) + z * S(-1.13596475577881948265e-11))))));
    V hz = S(0.5) * z, w = ONE - hz;
    V co = w + (((ONE - w) - hz) + z * pc);
    L n = __builtin_convertvector(q, L);
    L swap = (n & 1) != 0;
    L sgn = (L)S(-0.0);
    V s1 = SEL(swap, co, si), c1 = SEL(swap, si, co);
    *sn = (V)((L)s1 ^ (((n & 2) != 0) & sgn));
    *cs = (V)((L)c1 ^ ((((n + 1) & 2) != 0) & sgn));
    if (__builtin_expect(out[0] | out[1] | out[2] | out[3], 0))
        for (int l = 0; l < 4; l++) if (out[l]) { (*sn)[l] = sin(x[l]); (*cs)[l] = cos(x[l]); }
}
static inline V vsin(V a) { V s, c; vsincos(a, &s, &c); return s; }
static inline V vcos(V a) { V s, c; vsincos(a, &s, &c); return c; }
static inline V vexp(V a) { return _ZGVdN4v_exp(a); }
static inline V vlog(V a) { return _ZGVdN4v_log(a); }
static inline V vsqrt(V a) { return __builtin_ia32_sqrtpd256(a); }
static inline V vif0(V c, V y) { return (V)((c != ZERO) & (L)y); }
#define LANE1(name, fn) static inline V name(V a) { V r; \
    for (int l = 0; l < 4; l++) r[l] = fn(a[l]); return r; }
#define LANE2(name, fn) static inline V name(V a, V b) { V r; \
    for (int l = 0; l < 4; l++) r[l] = fn(a[l], b[l]); return r; }
static inline double sign_(double x) { return x > 0 ? 1.0 : (x < 0 ? -1.0 : x); }
LANE1(vabs, fabs) LANE1(vtan, tan) LANE1(vasin, asin) LANE1(vacos, acos)
LANE1(vatan, atan) LANE1(vfloor, floor) LANE1(vceil, ceil) LANE1(vsign, sign_)
LANE1(vtanh, tanh) LANE2(vmin, fmin) LANE2(vmax, fmax) LANE2(vatan2, atan2)
LANE2(vpow, pow)
"""
_OPS = {
    ca.OP_ASSIGN: "{0}", ca.OP_ADD: "{0} + {1}", ca.OP_SUB: "{0} - {1}",
    ca.OP_MUL: "{0} * {1}", ca.OP_DIV: "{0} / {1}", ca.OP_NEG: "-{0}",
    ca.OP_SQ: "{0} * {0}", ca.OP_TWICE: "{0} + {0}", ca.OP_INV: "ONE / {0}",
    ca.OP_SIN: "vsin({0})", ca.OP_COS: "vcos({0})", ca.OP_EXP: "vexp({0})",
    ca.OP_LOG: "vlog({0})", ca.OP_SQRT: "vsqrt({0})", ca.OP_FABS: "vabs({0})",
    ca.OP_TAN: "vtan({0})", ca.OP_ASIN: "vasin({0})", ca.OP_ACOS: "vacos({0})",
    ca.OP_ATAN: "vatan({0})", ca.OP_TANH: "vtanh({0})", ca.OP_FLOOR: "vfloor({0})",
    ca.OP_CEIL: "vceil({0})", ca.OP_SIGN: "vsign({0})", ca.OP_FMIN: "vmin({0}, {1})",
    ca.OP_FMAX: "vmax({0}, {1})", ca.OP_ATAN2: "vatan2({0}, {1})",
    ca.OP_POW: "vpow({0}, {1})", ca.OP_CONSTPOW: "vpow({0}, {1})",
    ca.OP_IF_ELSE_ZERO: "vif0({0}, {1})", ca.OP_LT: "B({0} < {1})",
    ca.OP_LE: "B({0} <= {1})", ca.OP_EQ: "B({0} == {1})", ca.OP_NE: "B({0} != {1})",
    ca.OP_NOT: "B({0} == ZERO)", ca.OP_AND: "B(({0} != ZERO) & ({1} != ZERO))",
    ca.OP_OR: "B(({0} != ZERO) | ({1} != ZERO))",
}


_SLOT = 64           # value ids: 64 k + i for output i of instruction k


def _callee(f: ca.Function, k: int) -> ca.Function:
    """The Function that instruction k of ``f`` (an OP_CALL) calls: the one called
    Function with as many input and output nonzeros as the call."""
    n_in, n_out = len(f.instruction_input(k)), len(f.instruction_output(k))
    found = {g.name(): g for g in f.find_functions(1)
             if sum(g.nnz_in(i) for i in range(g.n_in())) == n_in
             and sum(g.nnz_out(i) for i in range(g.n_out())) == n_out}
    if len(found) != 1 or n_out >= _SLOT:
        raise _Untranslatable(f"{f.name()}: instruction {k} calls a Function this "
                                  "translator cannot identify")
    return next(iter(found.values()))


def _trig_plan(f: ca.Function):
    """Which sines and cosines ``f`` needs and how to get them.

    A value is named by the instruction that produces it (64 k + i, i the output of a
    call).  Returns the arguments of ``f``'s sines and cosines (with the values their
    sums need), ``derived`` ({value: (op, children)}: a sum, difference, negation or
    double of values whose sine and cosine are known, by the addition formulas; the
    others take one ``vsincos`` each) and each instruction's input values."""
    writer, ins, op_of = {}, {}, {}
    for k in range(f.n_instructions()):
        op, a = f.instruction_id(k), f.instruction_input(k)
        if op not in _OPS and op not in (ca.OP_INPUT, ca.OP_OUTPUT, ca.OP_CONST, ca.OP_CALL):
            raise _Untranslatable(f"{f.name()}: operation {op} has no vector form")
        op_of[k] = op
        if op not in (ca.OP_INPUT, ca.OP_CONST):
            ins[k] = [writer[i] for i in a] if op != ca.OP_OUTPUT else []
        if op == ca.OP_CALL:
            for i, r in enumerate(f.instruction_output(k)):
                if r >= 0:
                    writer[r] = _SLOT * k + i
        elif op != ca.OP_OUTPUT:
            writer[f.instruction_output(k)[0]] = _SLOT * k

    def op_at(v):
        return op_of[v // _SLOT] if v % _SLOT == 0 else ca.OP_CALL

    def ins_at(v):
        return ins.get(v // _SLOT, []) if v % _SLOT == 0 else []

    args = {ins[k][0] for k in op_of if op_of[k] in (ca.OP_SIN, ca.OP_COS)}
    derived = {}

    def known(v, depth):
        """Can the sine and cosine of v come from those of arguments, through at most
        ``depth`` sums and differences of values that are not arguments?"""
        if v in args:
            return True
        return depth > 0 and op_at(v) in (ca.OP_ADD, ca.OP_SUB) and all(
            known(c, depth - 1) for c in ins_at(v))

    def derive(v):
        op, ch = op_at(v), ins_at(v)
        if op in (ca.OP_ADD, ca.OP_SUB) and all(known(c, 2) for c in ch):
            derived[v] = (op, ch)
            for c in ch:
                if c not in args:
                    derive(c)
        elif op in (ca.OP_NEG, ca.OP_TWICE) and ch[0] in args:
            derived[v] = (op, ch)

    # a value that is not an argument but a summand of two or more (a coordinate whose
    # own sine is not needed) is worth one vsincos: the sums then come from it
    count = {}
    for v in args:
        if op_at(v) in (ca.OP_ADD, ca.OP_SUB):
            out = [c for c in ins_at(v) if c not in args]
            if len(out) == 1:
                count[out[0]] = count.get(out[0], 0) + 1
    args = args | {c for c, n in count.items() if n >= 2}
    for v in sorted(args):                          # children come before parents
        derive(v)
    return args | set(derived), derived, ins


_COMBINE = {
    ca.OP_ADD: ("ts{b} * tc{c} + tc{b} * ts{c}", "tc{b} * tc{c} - ts{b} * ts{c}"),
    ca.OP_SUB: ("ts{b} * tc{c} - tc{b} * ts{c}", "tc{b} * tc{c} + ts{b} * ts{c}"),
    ca.OP_NEG: ("-ts{b}", "tc{b}"),
    ca.OP_TWICE: ("S(2.0) * ts{b} * tc{b}", "tc{b} * tc{b} - ts{b} * ts{b}"),
}


def _body(f: ca.Function):
    """The C statements of ``f`` on vector work variables ``w<i>``: inputs from
    ``in<i>[nz]``, outputs to ``out<i>[nz]`` (arrays of V); and the Functions it calls.

    Sines and cosines are the costly instructions on four lanes, so they are planned
    (:func:`_trig_plan`): the sine and the cosine of one value share one ``vsincos``, and
    the sine and cosine of a sum of such values (the model's angles are sums of
    coordinates) come from the addition formulas.  A call of another Function (a
    B-spline, say) runs CasADi's generated C for it lane by lane."""
    if not f.is_a("SXFunction"):
        raise _Untranslatable(f"{f.name()}: only SX Functions translate")
    args, derived, ins = _trig_plan(f)
    base = sorted(args - set(derived))
    done, callees = set(), {}
    lines = [f"V {', '.join(f'w{i}' for i in range(f.sz_w()))};"] if f.sz_w() else []
    if args:
        lines.append(f"V {', '.join(f'ts{v}, tc{v}' for v in sorted(args))};")
    if base:
        lines.append(f"V {', '.join(f'a{v}' for v in base)};")
    base = set(base)

    def ensure(v):
        if v in done:
            return
        if v in derived:
            op, ch = derived[v]
            for c in ch:
                ensure(c)
            sn, cs = _COMBINE[op]
            fmt = dict(b=ch[0], c=ch[-1])
            lines.append(f"ts{v} = {sn.format(**fmt)}; tc{v} = {cs.format(**fmt)};")
        else:
            lines.append(f"vsincos(a{v}, &ts{v}, &tc{v});")
        done.add(v)

    for k in range(f.n_instructions()):
        op = f.instruction_id(k)
        a, r = f.instruction_input(k), f.instruction_output(k)
        if op == ca.OP_INPUT:
            lines.append(f"w{r[0]} = in{a[0]}[{a[1]}];")
        elif op == ca.OP_OUTPUT:
            lines.append(f"out{r[0]}[{r[1]}] = w{a[0]};")
        elif op == ca.OP_CONST:
            lines.append(f"w{r[0]} = S({float(f.instruction_constant(k))!r});")
        elif op == ca.OP_CALL:
            g = _callee(f, k)
            callees[g.name()] = g
            lines.append(_call(g, a, r))
        elif op in (ca.OP_SIN, ca.OP_COS):
            v = ins[k][0]
            ensure(v)
            lines.append(f"w{r[0]} = {'ts' if op == ca.OP_SIN else 'tc'}{v};")
        else:
            lines.append(f"w{r[0]} = " + _OPS[op].format(*(f"w{i}" for i in a)) + ";")
        for i, w in enumerate(r if op == ca.OP_CALL else r[:1]):
            if _SLOT * k + i in base:        # keep the argument: its register is reused
                lines.append(f"a{_SLOT * k + i} = w{w};")
    code = "\n    ".join(lines).replace("S(nan)", "S(NAN)").replace("S(inf)", "S(INFINITY)") \
        .replace("S(-inf)", "S(-INFINITY)")
    return code, callees


def _call(g: ca.Function, a, r) -> str:
    """C that calls CasADi's code of ``g`` once per lane: inputs from the work variables
    ``a`` (g's input nonzeros in order), outputs to ``r`` (-1: unused)."""
    offs_in = np.cumsum([0] + [g.nnz_in(i) for i in range(g.n_in())])
    offs_out = np.cumsum([0] + [g.nnz_out(i) for i in range(g.n_out())])
    ar = ", ".join(f"ci + {o}" for o in offs_in[:-1])
    rs = ", ".join(f"co + {o}" for o in offs_out[:-1])
    load = " ".join(f"ci[{j}] = w{w}[l];" for j, w in enumerate(a))
    store = " ".join(f"w{w}[l] = co[{j}];" for j, w in enumerate(r) if w >= 0)
    return (f"{{ double ci[{max(1, len(a))}], co[{max(1, len(r))}]; "
            f"long long iw_[{g.sz_iw() + 1}]; double w_[{g.sz_w() + 1}]; "
            f"const double* ar[{g.sz_arg() + 1}] = {{{ar}}}; "
            f"double* rs[{g.sz_res() + 1}] = {{{rs}}}; "
            f"for (int l = 0; l < 4; l++) {{ {load} {g.name()}(ar, rs, iw_, w_, 0); {store} }} }}")


def _callee_source(g: ca.Function, n: int) -> str:
    """CasADi's C of ``g``, its internal symbols prefixed (one translation unit each)."""
    cg = ca.CodeGenerator(f"{g.name()}.c", {"with_header": False})
    cg.add(g)
    return f"#define CASADI_CODEGEN_PREFIX\n#define CODEGEN_PREFIX cg{n}_\n" + cg.dump()


@functools.lru_cache(maxsize=1)
def _cpu() -> str:
    """The CPU's model and flags (``-march=native`` code is for this CPU only)."""
    try:
        with open("/proc/cpuinfo") as fh:
            lines = fh.read().splitlines()
    except OSError:
        return ""
    return "".join(x + "\n" for x in lines if x.startswith(("model name", "flags")))


@functools.lru_cache(maxsize=1)
def available() -> bool:
    """Whether the kernels can run here (checked once per process).

    Returns
    -------
    bool
        True on an x86-64 CPU with AVX2 and FMA, with gcc on the path.
    """
    flags = _cpu().split()
    if "avx2" not in flags or "fma" not in flags:
        return False
    try:
        subprocess.run(["gcc", "--version"], check=True, capture_output=True)
        return True
    except (OSError, subprocess.CalledProcessError):
        return False


_FLAGS = ["-march=native", "-fno-math-errno", "-fno-trapping-math", "-fPIC"]


def _digest(*parts: str) -> str:
    return hashlib.sha256("\0".join(parts).encode()).hexdigest()[:16]


def _object(name: str, source: str, flags) -> str:
    """One translation unit compiled once per content, flags and CPU into the cache
    folder: the path of its object file."""
    key = _digest(source, " ".join(flags), _cpu())

    def build(tmp, out):
        c = os.path.join(tmp, f"{name}.c")
        with open(c, "w") as fh:
            fh.write(source)
        subprocess.run(["gcc", *flags, "-c", c, "-o", out], check=True, capture_output=True)

    return str(cached_library(f"{name}_{key}.o", build))


def _library(name: str, sources, optimisation: str = "-O2"):
    """Compile the C ``sources`` (one translation unit each, each kept as an object file
    by its content: a unit shared by several libraries, such as a walker's node for
    every gait of a robot, is compiled once) and link them once per set into the cache
    folder (:func:`~biped_casadi.numerics.cached_library`): the library's path."""
    flags = [optimisation, *_FLAGS]
    objects = [_object(name, src, flags) for src in sources]
    key = _digest(*(os.path.basename(o) for o in objects))

    def build(tmp, out):
        subprocess.run(["gcc", "-shared", *objects, "-o", out, "-lmvec", "-lm"],
                       check=True, capture_output=True)

    return cached_library(f"{name}_simd_{key}.so", build)


@functools.lru_cache(maxsize=1)
def _translator() -> str:
    """A digest of this module's source, which the C is generated by."""
    try:
        with open(__file__, "rb") as fh:
            return hashlib.sha256(fh.read()).hexdigest()
    except OSError:               # unreadable: a digest of its own, nothing reused
        return os.urandom(16).hex()


#: the libraries this process has loaded, by the digest of what they are generated from
_LOADED: dict = {}


def _kernels_library(name: str, maps: dict, optimisation: str) -> ctypes.CDLL:
    """The library of ``maps``; translated and compiled only when the cache folder has no
    library of the same Functions yet.

    Translating (:func:`_body`: about 0.1 s for a walker's Functions) is done once: an
    index file, named by a digest of the Functions' serialisations, the kernels'
    settings, this module's source, CasADi's version, the flags and the CPU, holds the
    library's file name."""
    key = _digest(name, optimisation, " ".join(_FLAGS), _cpu(), ca.__version__,
                  _translator(), *(f"{k!r} {m.n_acc} {m.kinds!r} {m.last} " + m.f.serialize()
                                   for k, m in maps.items()))
    if key in _LOADED:
        return _LOADED[key]

    def sources():
        parts = [m._source() for m in maps.values()]
        callees = {}
        for _, c in parts:
            callees.update(c)
        decl = "".join(f"int {g}(const double**, double**, long long*, double*, int);\n"
                       for g in callees)
        # one unit per kernel and per callee: each is compiled once wherever it recurs
        return [_HEADER + decl + code for code, _ in parts] + \
            [_callee_source(g, n) for n, g in enumerate(callees.values())]

    def build(tmp, out):
        with open(out, "w") as fh:
            fh.write(_library(name, sources(), optimisation).name)

    index = cached_library(f"{name}_simd_{key}.idx", build)
    try:
        held = index.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError):
        held = ""
    so = index.parent / held
    if not (re.fullmatch(rf"{re.escape(name)}_simd_[0-9a-f]{{16}}\.so", held)
            and so.is_file()):
        # the library was removed from the cache folder, or the index is damaged (not a
        # library's name): made again (from its objects when they are kept), and a
        # damaged index replaced
        so = _library(name, sources(), optimisation)
        if held != so.name:
            with contextlib.suppress(OSError):     # a full disk: made again next time
                write_text_atomic(index, so.name)
    return _LOADED.setdefault(key, ctypes.CDLL(str(so)))


class AccumulatedMap:
    """``f.mapaccum(K)`` over a batch of scenarios, compiled to four-lane C.

    Built by :func:`kernels` (one shared library for several Functions).

    Parameters
    ----------
    f : casadi.Function
        An SX Function of one scenario and one node; its first ``n_acc`` inputs are
        the state, replaced after every node by its first ``n_acc`` outputs (same sizes).
    n_acc : int
        How many leading inputs are accumulated (0: a plain map, called with K = 1).
    kinds : sequence of str
        For each input after the accumulated ones: ``"sample"`` (one column per
        scenario, constant along the nodes), ``"node"`` (one column per node, the same
        for every scenario) or ``"const"`` (one column for all).
    last : bool
        Keep the outputs of the last node only (K = 1 in the returned arrays).

    Notes
    -----
    Calling it with the accumulated inputs' start values and the other inputs (each an
    (n_i, N) array for ``"sample"`` and the accumulated ones, (n_i, K) for ``"node"``,
    (n_i,) for ``"const"``) returns every output at every node, (n_out, N, K) arrays.
    """

    def __init__(self, f: ca.Function, n_acc: int, kinds, last: bool = False):
        kinds = tuple(kinds)
        if len(kinds) + n_acc != f.n_in():
            raise ValueError(f"{f.name()}: {f.n_in()} inputs, {n_acc} accumulated + "
                             f"{len(kinds)} kinds given")
        for i in range(n_acc):
            if f.nnz_in(i) != f.nnz_out(i):
                raise ValueError(f"{f.name()}: accumulated input {i} and output {i} differ "
                                 "in size")
        for i in range(f.n_in()):
            if not f.sparsity_in(i).is_dense():
                raise _Untranslatable(f"{f.name()}: input {i} is sparse")
        self.f, self.n_acc, self.kinds = f, n_acc, ("acc",) * n_acc + kinds
        self.n_in = [f.nnz_in(i) for i in range(f.n_in())]
        self.n_out = [f.nnz_out(i) for i in range(f.n_out())]
        self.name = f.name()
        self.last = bool(last)
        self._run = None

    def _bind(self, lib: ctypes.CDLL):
        self._run = getattr(lib, f"run_{self.name}")
        self._run.restype = None
        self._run.argtypes = [ctypes.c_int] * 4 + [ctypes.c_void_p] * (
            len(self.n_in) + len(self.n_out))

    def _source(self):
        """The C of this kernel and the Functions it calls.

        Returns
        -------
        code : str
            ``node_<name>`` (one node on four lanes) and ``run_<name>`` (the nodes of
            scenarios s0..s1).
        callees : dict
            {name: casadi.Function} called from the node (their C is CasADi's).
        """
        ni, no, nm = self.n_in, self.n_out, self.name
        body, callees = _body(self.f)
        args = ", ".join(f"const V* in{i}" for i in range(len(ni)))
        outs = ", ".join(f"V* out{i}" for i in range(len(no)))
        ptrs = ", ".join([f"const double* I{i}" for i in range(len(ni))]
                         + [f"double* O{i}" for i in range(len(no))])
        decl = [f"V in{i}[{ni[i]}];" for i in range(len(ni))] + \
               [f"V out{i}[{no[i]}];" for i in range(len(no))]
        load, per_node, step = [], [], []
        for i, kind in enumerate(self.kinds):
            if kind in ("acc", "sample"):      # (n_i, N): lanes from columns s..s+3
                load.append(f"for (int j = 0; j < {ni[i]}; j++) for (int l = 0; l < 4; l++)"
                            f" in{i}[j][l] = I{i}[(long)j * N + col[l]];")
            elif kind == "const":
                load.append(f"for (int j = 0; j < {ni[i]}; j++) in{i}[j] = S(I{i}[j]);")
            else:                              # (n_i, K): node k's column, every lane
                per_node.append(f"for (int j = 0; j < {ni[i]}; j++) in{i}[j] = "
                                f"S(I{i}[(long)j * K + k]);")
        for i in range(self.n_acc):
            step.append(f"for (int j = 0; j < {ni[i]}; j++) in{i}[j] = out{i}[j];")
        where = "(long)j * N + s + l" if self.last else "((long)j * N + s + l) * K + k"
        store = [("if (k == K - 1) " if self.last else "")
                 + f"for (int j = 0; j < {no[i]}; j++) for (int l = 0; l < nl; l++) "
                 f"O{i}[{where}] = out{i}[j][l];"
                 for i in range(len(no))]
        nl = "\n        "
        code = f"""
static inline void node_{nm}({args}, {outs}) {{
    {body}
}}

void run_{nm}(int N, int K, int s0, int s1, {ptrs}) {{
    {' '.join(decl)}
    for (int s = s0; s < s1; s += 4) {{
        int nl = s1 - s < 4 ? s1 - s : 4, col[4];
        for (int l = 0; l < 4; l++) col[l] = s + (l < nl ? l : nl - 1);
        {nl.join(load)}
        for (int k = 0; k < K; k++) {{
            {nl.join(per_node)}
            node_{nm}({', '.join(f'in{i}' for i in range(len(ni)))},
                 {', '.join(f'out{i}' for i in range(len(no)))});
            {nl.join(store)}
            {nl.join(step)}
        }}
    }}
}}
"""
        return code, callees

    def __call__(self, *inputs, K: int = 1, threads: int = 1):
        """Run K nodes of every scenario.

        Parameters
        ----------
        *inputs : array_like
            One per input of ``f``, shaped by its kind (see Notes of the class).
        K : int
            Nodes (1 for a plain map).
        threads : int
            Threads the scenarios are split over.

        Returns
        -------
        list of numpy.ndarray
            Every output after every node, (n_out, N, K) each ((n_out, N, 1): after the
            last node, for a map built with ``last``).
        """
        if len(inputs) != len(self.kinds):
            raise ValueError(f"{self.name}: {len(self.kinds)} inputs, got {len(inputs)}")
        N = None
        arrs = []
        for i, (x, kind) in enumerate(zip(inputs, self.kinds)):
            a = np.asarray(x, dtype=float)
            if kind in ("acc", "sample"):
                a = a.reshape(self.n_in[i], -1)
                if N is None:
                    N = a.shape[1]
                elif a.shape[1] != N:
                    raise ValueError(f"{self.name}: input {i} has {a.shape[1]} scenarios, "
                                     f"expected {N}")
            elif kind == "node":
                a = a.reshape(self.n_in[i], K)
            else:
                a = a.reshape(self.n_in[i])
            arrs.append(np.ascontiguousarray(a))
        if N is None:
            raise ValueError(f"{self.name}: no per-scenario input")
        outs = [np.empty((n, N, 1 if self.last else K)) for n in self.n_out]
        if N == 0:
            return outs
        ptrs = [a.ctypes.data for a in arrs] + [o.ctypes.data for o in outs]
        parts = max(1, min(int(threads), N // (2 * LANES)))
        edges = [LANES * ((N // LANES) * p // parts) for p in range(parts)] + [N]
        if parts == 1:
            self._run(N, K, 0, N, *ptrs)
        else:
            list(_pool(parts).map(lambda p: self._run(N, K, edges[p], edges[p + 1], *ptrs),
                                  range(parts)))
        return outs


def kernels(specs, name: str = "kernels", optimisation: str = "-O2") -> dict | None:
    """Several :class:`AccumulatedMap` compiled into one shared library.

    One compiler run, the library kept in the cache folder by content and CPU.

    Parameters
    ----------
    specs : dict
        ``{key: (f, n_acc, kinds)}`` or ``{key: (f, n_acc, kinds, last)}`` (the
        arguments of :class:`AccumulatedMap`); the Functions' names must differ.
    name : str
        The library's name in the cache folder.
    optimisation : str
        The compiler's optimisation flag (``"-O1"`` compiles about twice as fast).

    Returns
    -------
    dict or None
        ``{key: AccumulatedMap}``, or None where the kernels cannot be built here (no
        AVX2, no C compiler, an instruction without a vector form, a failing compile).
    """
    if not available():
        return None
    try:
        maps = {k: AccumulatedMap(*v) for k, v in specs.items()}
        if len({m.name for m in maps.values()}) != len(maps):
            raise ValueError("kernels: the Functions' names must differ")
        lib = _kernels_library(name, maps, optimisation)
    except _Untranslatable:
        return None
    except (OSError, subprocess.CalledProcessError) as e:
        note_not_compiled(e)
        return None
    for m in maps.values():
        m._bind(lib)
    return maps


_POOLS: dict = {}


def _pool(n: int) -> ThreadPoolExecutor:
    """One thread pool per size, kept for the process."""
    if n not in _POOLS:
        _POOLS[n] = ThreadPoolExecutor(n, thread_name_prefix="simd")
    return _POOLS[n]
