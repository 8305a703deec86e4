"""One domain of a hybrid cycle (:mod:`analysis.stability.hybrid_cycle`): its Functions
and their sizes, checked when it is built, and the error a cycle raises naming it."""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

__all__ = ["Domain", "HybridCycleError"]


class HybridCycleError(ValueError):
    """A domain of a cycle that cannot be built or traversed (one line, naming it).

    The message starts with the domain's name: "domain 'flight': ...".

    Parameters
    ----------
    domain : str
        The domain's name (kept as the attribute ``domain``).
    kind : str
        'no_crossing' (the guard is not crossed within the domain's time limit),
        'dimension' (a reset, entry or vector field of the wrong size), 'constraint' (a
        validity constraint violated), 'not_finite' (the state diverged), 'edge' (a
        state on the edge between two sequences of domains, where central differences
        are refused: :func:`~analysis.stability.hybrid_cycle.finite_difference_jacobian`);
        kept as the attribute ``kind``.
    message : str
        What happened, after the domain's name.
    """

    def __init__(self, domain: str, kind: str, message: str):
        self.domain, self.kind = domain, kind
        super().__init__(f"domain '{domain}': {message}")


def _size(f: ca.Function, i: int, out: bool = False) -> int:
    return f.numel_out(i) if out else f.numel_in(i)


@dataclass
class Domain:
    """One domain of a hybrid cycle (:mod:`analysis.stability.hybrid_cycle`).

    Parameters
    ----------
    name : str
        Named in every error.
    n : int
        Size of the domain's state x (the previous reset's output, this reset's input).
    vector_field : casadi.Function
        ``f(X, t, p) -> dX/dt``: the closed loop on the augmented state X (``nX``
        numbers, X[:n] = x), t the time since entry, p the domain's parameters.
    guard : casadi.Function
        ``g(X, t, p)`` (m numbers, the guard's parts; m = 1 a scalar guard): the domain
        ends where the first part crosses zero going down.
    reset : casadi.Function or tuple of casadi.Function
        ``Delta(x) -> x+`` (first output), x = X[:n] at the crossing, x+ the next
        domain's state; or one per part of the guard, the reset of the part that fired
        (all of the same sizes).
    h : float
        RK4 step, s.
    t_max : float
        Time limit: the guard must be crossed within it, s.
    start : casadi.Function, optional
        ``start(x) -> (X0, p)`` at entry, or ``start(x, s) -> (X0, p)`` with s the time
        the stride has run before this domain since the entry of domain ``clock_from``
        (the durations of the domains from that one to this one's predecessor; 0 in the
        cycle's first domain); default X0 = x, no parameters.
    arming : casadi.Function, optional
        ``a(X, t, p)`` (scalar): a crossing counts only at a node where a > 0 (the
        swing foot in front of the stance foot).
    constraints : casadi.Function, optional
        ``c(X, t, p)`` (m numbers): c >= -``tolerance`` at every node before the
        crossing and at the crossing.
    constraint_names : tuple of str
        One per entry of c (default 'constraint 0', ...).
    exit_constraints : casadi.Function, optional
        ``e(x)`` (k numbers) >= -``tolerance`` at the crossing, e.g. the landing
        impulse and the lift-off of the other foot.
    exit_constraint_names : tuple of str
        One per entry of e.
    guard_name : str
        The guard in words.
    guard_parts : tuple of str
        One name per part of the guard (default ``(guard_name,)`` for a scalar guard,
        else 'guard part 0', ...): the pass's ``part``, and the name of its dips.
    skip : tuple of int
        One per part (default all 0): where that part fires, the next ``skip[k]``
        domains are empty (each a pass of duration 0 whose reset, which must not depend
        on a part, acts on its entry state; ``part`` None).  They must lie before the
        cycle's end.
    tolerance : float
        How far below zero a constraint may go (round-off), in its own unit.
    dense_constraints : tuple of str
        Names of constraints (of ``constraint_names``) that must also hold between the
        nodes (:mod:`analysis.stability.between_nodes`): screened at every step by the
        nodes' values, their rates taken only where a step may dip below the bound.
    dense_guard : bool
        Look for the guard's crossing between the nodes too: a dip below 0 and back within
        one RK4 step ends the domain at its first root.
    clock_from : int
        The domain (its index in the cycle, at most this one's) from whose entry the s of
        ``start(x, s)`` is counted; 0: from the stride's start.
    may_be_empty : bool
        A guard part at or below 0 at entry ends the domain there (the first such part
        fires): a pass of duration 0 whose reset acts on the entry state (the domain's
        constraints, which hold inside it, are not checked; its exit constraints are).
        Without it such a part waits for a crossing from >= 0.
    common_subexpressions : bool
        Merge the equal subexpressions of the RK4 step's sensitivities (``casadi.cse``)
        when the Functions are built: it halves a walking domain's linearisation but
        costs a running domain seconds of build for no faster evaluation.
    discrete_parameters : tuple of int
        Places in p of the parameters that ``start`` sets as a discrete choice (a sign,
        a flag: a sliding foot's direction), constant between the states where the
        choice changes.  The stride map is another piece of the hybrid map where a
        lasting domain's choice differs: central differences keep each column's step
        where x's choices hold
        (:func:`~analysis.stability.hybrid_cycle.finite_difference_jacobian`).
    """

    name: str
    n: int
    vector_field: ca.Function
    guard: ca.Function
    reset: ca.Function
    h: float
    t_max: float
    start: ca.Function | None = None
    arming: ca.Function | None = None
    constraints: ca.Function | None = None
    constraint_names: tuple = ()
    exit_constraints: ca.Function | None = None
    exit_constraint_names: tuple = ()
    guard_name: str = "guard"
    guard_parts: tuple = ()
    skip: tuple = ()
    tolerance: float = 0.0
    dense_constraints: tuple = ()
    dense_guard: bool = False
    clock_from: int = 0
    may_be_empty: bool = False
    common_subexpressions: bool = True
    discrete_parameters: tuple = ()

    def __post_init__(self):
        f = self.vector_field
        if not isinstance(f, ca.Function) or f.n_in() != 3:
            raise HybridCycleError(self.name, "dimension",
                                   "vector_field must be a casadi.Function f(X, t, p)")
        self.nX, self.n_par = _size(f, 0), _size(f, 2)
        if _size(f, 0, out=True) != self.nX:
            raise HybridCycleError(self.name, "dimension",
                                   f"the vector field gives {_size(f, 0, out=True)} numbers "
                                   f"for a state of {self.nX}")
        if self.n > self.nX:
            raise HybridCycleError(self.name, "dimension",
                                   f"state of {self.n} numbers, but the vector field "
                                   f"integrates {self.nX}")
        if self.start is None:
            if self.nX != self.n or self.n_par:
                raise HybridCycleError(self.name, "dimension",
                                       "a start(x) -> (X0, p) is needed when the vector "
                                       "field's state or parameters are not x alone")
        else:
            got = (_size(self.start, 0), _size(self.start, 0, True), _size(self.start, 1, True))
            if self.start.n_in() not in (1, 2) or (self.start.n_in() == 2
                                                    and _size(self.start, 1) != 1):
                raise HybridCycleError(self.name, "dimension",
                                       "start takes x, or x and the stride's time s (one "
                                       "number)")
            if got != (self.n, self.nX, self.n_par):
                raise HybridCycleError(self.name, "dimension",
                                       f"start maps {got[0]} numbers to ({got[1]}, {got[2]}), "
                                       f"expected {self.n} to ({self.nX}, {self.n_par})")
        for what in ("guard", "arming", "constraints"):
            g = getattr(self, what)
            if g is None:
                continue
            sizes = tuple(_size(g, i) for i in range(g.n_in()))
            if sizes != (self.nX, 1, self.n_par):
                raise HybridCycleError(self.name, "dimension",
                                       f"{what} takes {sizes}, expected (X, t, p) of "
                                       f"{(self.nX, 1, self.n_par)}")
        if self.arming is not None and _size(self.arming, 0, True) != 1:
            raise HybridCycleError(self.name, "dimension", "arming must be a scalar")
        self._parts()
        self.discrete_parameters = tuple(self.discrete_parameters)
        if any(isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer))
               or not 0 <= i < self.n_par for i in self.discrete_parameters):
            raise HybridCycleError(self.name, "dimension",
                                   f"discrete_parameters must be places in the domain's "
                                   f"{self.n_par} parameters, got {self.discrete_parameters!r}")
        if self.exit_constraints is not None and _size(self.exit_constraints, 0) != self.n:
            raise HybridCycleError(self.name, "dimension",
                                   f"exit_constraints take {_size(self.exit_constraints, 0)} "
                                   f"numbers, the domain's state has {self.n}")
        self.max_steps = int(np.ceil(self.t_max / self.h - 1e-9))
        self.constraint_names = self._names(self.constraints, self.constraint_names,
                                            "constraint")
        self.exit_constraint_names = self._names(self.exit_constraints,
                                                 self.exit_constraint_names, "exit constraint")
        unknown = [c for c in self.dense_constraints if c not in self.constraint_names]
        if unknown:
            raise HybridCycleError(self.name, "dimension",
                                   f"dense_constraints names no constraint {unknown[0]!r}")
        m = len(self.part_names)
        #: the outputs checked between the nodes: (name, place in (the guard's parts, the
        #: constraints)), a guard part where the place is below m
        self.watched = ((tuple((nm, k) for k, nm in enumerate(self.part_names))
                         if self.dense_guard else ())
                        + tuple((c, m + self.constraint_names.index(c))
                                for c in self.dense_constraints))
        #: their bounds (0 for the guard's parts, -tolerance for a constraint) and places
        self.watched_bounds = np.array([0.0 if i < m else -self.tolerance
                                        for _, i in self.watched])
        self.watched_index = np.array([i for _, i in self.watched], int)

    def _parts(self):
        """The guard's parts, their names, resets and skips (``part_names``, ``resets``,
        ``skips``)."""
        g = self.guard
        m = _size(g, 0, True)
        if m < 1 or g.size2_out(0) != 1:
            raise HybridCycleError(self.name, "dimension",
                                   "the guard must be a column of one or more parts")
        self.part_names = self._names(g, self.guard_parts or ((self.guard_name,) if m == 1
                                                              else ()), "guard part")
        resets = (self.reset,) * m if isinstance(self.reset, ca.Function) else tuple(self.reset)
        if len(resets) != m or not all(isinstance(r, ca.Function) for r in resets):
            raise HybridCycleError(self.name, "dimension",
                                   f"reset must be a casadi.Function or one per part of the "
                                   f"guard ({m})")
        for r in resets:
            if _size(r, 0) != self.n:
                raise HybridCycleError(self.name, "dimension",
                                       f"the reset takes {_size(r, 0)} numbers, the "
                                       f"domain's state has {self.n}")
        if len({_size(r, 0, True) for r in resets}) != 1:
            raise HybridCycleError(self.name, "dimension",
                                   "the parts' resets give states of different sizes")
        skip = tuple(self.skip) or (0,) * m
        if len(skip) != m or any(isinstance(v, (bool, np.bool_))
                                 or not isinstance(v, (int, np.integer)) or v < 0 for v in skip):
            raise HybridCycleError(self.name, "dimension",
                                   f"skip must be {m} whole numbers >= 0, one per part of the "
                                   f"guard, got {self.skip!r}")
        self.resets, self.skips = resets, tuple(int(v) for v in skip)

    def _names(self, f, names, word):
        if f is None:
            return ()
        m = _size(f, 0, True)
        names = tuple(names) or tuple(f"{word} {i}" for i in range(m))
        if len(names) != m:
            raise HybridCycleError(self.name, "dimension",
                                   f"{len(names)} names for {m} {word}s")
        return names

    @property
    def n_next(self) -> int:
        """Size of the reset's output, the next domain's state."""
        return _size(self.resets[0], 0, out=True)
