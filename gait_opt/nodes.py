"""Sampled gaits from other tools: one step as nodes (t, q, dq[, ddq]) read from CSV,
NPZ or JSON, validated, and converted from absolute link angles when asked.

Formats (one step, from just after an impact to just before the next; times in s,
angles in rad, nodes not necessarily uniform, at least :data:`MIN_NODES`):

- CSV: a header ``t,q1,...,qn,dq1,...,dqn`` (optionally ``,ddq1,...,ddqn``), then one
  row per node;
- NPZ or JSON: arrays ``t`` (N,), ``q`` and ``dq`` (N, n; (n, N) is accepted too when
  N != n) and optionally ``ddq``.

Coordinates: the toolkit's (relative joint angles, docs/theory.md), or with
``angles='absolute'`` the absolute link angles phi_1..phi_n (phi_1 the stance leg's
lowest link, ..., the swing leg's lowest link last), converted by q_1 = phi_1,
q_i = phi_i - phi_{i-1}.
"""
from __future__ import annotations

import csv
import io
import json
import zipfile
from dataclasses import dataclass

import numpy as np

from biped_casadi.files import file_path, read_text_file

__all__ = ["Nodes", "nodes_from_arrays", "read_nodes", "relative_angles", "check_units",
           "MIN_NODES", "ANGLES", "RATE_RATIO", "COMMON_RATIO", "COMMON_SPREAD",
           "HALF_TURN_BEYOND", "HALF_TURN_WITHIN"]

#: fewer nodes than this cannot define a step
MIN_NODES = 5
#: how far (a factor either way) the angles' change over a step may be from what their
#: rates integrate to over t (trapezoids) before the nodes are refused as in other units
RATE_RATIO = 3.0
#: every moving coordinate off by one factor beyond this either way (agreeing within
#: :data:`COMMON_SPREAD`): t and the rates are on different time scales (t doubled)
COMMON_RATIO, COMMON_SPREAD = 1.3, 1.2
#: an angle beyond this (rad) where every other one stays within HALF_TURN_WITHIN is
#: refused as one in degrees (:func:`check_units`)
HALF_TURN_BEYOND = 4.0
HALF_TURN_WITHIN = 3.2
#: the coordinate conventions a sampled gait may be given in
ANGLES = ("relative", "absolute")


@dataclass
class Nodes:
    """One step as samples: times and the state (and accelerations) at each.

    Parameters
    ----------
    t : numpy.ndarray
        (N,) strictly increasing times, s.
    q, dq : numpy.ndarray
        (nq, N) rad and rad/s.
    ddq : numpy.ndarray or None
        (nq, N) rad/s^2 when given.
    source : str
        Where they came from (for messages).
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray | None = None
    source: str = "nodes"

    @property
    def n(self) -> int:
        """The number of nodes."""
        return self.t.size

    @property
    def nq(self) -> int:
        """The number of coordinates."""
        return self.q.shape[0]

    def every(self, k: int) -> "Nodes":
        """Every ``k``-th node, the last one kept.

        Parameters
        ----------
        k : int
            Stride.

        Returns
        -------
        Nodes
        """
        idx = np.unique(np.r_[np.arange(0, self.n, k), self.n - 1])
        return Nodes(self.t[idx], self.q[:, idx], self.dq[:, idx],
                     None if self.ddq is None else self.ddq[:, idx], self.source)


def _array(value, name: str, where: str) -> np.ndarray:
    try:
        a = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: {name} must be an array of numbers") from None
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{where}: {name} has a NaN or infinite value")
    return a


def nodes_from_arrays(t, q, dq, ddq=None, nq: int | None = None,
                      where: str = "nodes") -> Nodes:
    """Validated nodes from arrays.

    Parameters
    ----------
    t : array_like
        (N,) times, s, strictly increasing.
    q, dq : array_like
        (N, nq) or (nq, N); a square array (N = nq) is (N, nq).
    ddq : array_like, optional
        Same shape as q.
    nq : int, optional
        The robot's number of coordinates (checked when given).
    where : str
        Names the source in messages.

    Returns
    -------
    Nodes
        Arrays (nq, N).

    Raises
    ------
    ValueError
        Naming ``where`` and the array: not numbers, NaN, wrong shapes, times not
        strictly increasing, fewer than :data:`MIN_NODES` nodes.
    """
    t = _array(t, "t", where).ravel()
    if t.size < MIN_NODES:
        raise ValueError(f"{where}: {t.size} node(s); a step needs at least {MIN_NODES}")
    if not np.all(np.diff(t) > 0):
        i = int(np.argmax(~(np.diff(t) > 0)))
        raise ValueError(f"{where}: t must increase strictly (node {i + 2}: {t[i + 1]:g} "
                         f"after {t[i]:g})")
    out = []
    for name, a in (("q", q), ("dq", dq), ("ddq", ddq)):
        if a is None:
            out.append(None)
            continue
        a = _array(a, name, where)
        if a.ndim != 2 or t.size not in a.shape:
            raise ValueError(f"{where}: {name} must be an (N, n) array with N = {t.size} "
                             f"nodes, got shape {a.shape}")
        a = a.T if a.shape[0] == t.size else a      # (N, n); a square one is (N, n) too
        if nq is not None and a.shape[0] != nq:
            raise ValueError(f"{where}: {name} has {a.shape[0]} coordinates per node, the "
                             f"robot {nq}")
        out.append(a)
    if out[1].shape != out[0].shape or (out[2] is not None and out[2].shape != out[0].shape):
        raise ValueError(f"{where}: q, dq (and ddq) must have the same shape")
    return Nodes(t, out[0], out[1], out[2], where)


def check_units(t, q, dq, names, where: str = "nodes") -> None:
    """Refuse a step that is not in s, rad and rad/s, naming the column at fault.

    Angles in degrees (one that turns by more than a full turn over the step; one beyond
    a full turn, or beyond :data:`HALF_TURN_BEYOND` where the others stay within
    :data:`HALF_TURN_WITHIN`: a pitch in degrees beside joints in radians), then rates
    that do not integrate to the angles by a factor beyond :data:`RATE_RATIO` either way
    (t in ms, rates in deg/s).  Each would otherwise be refused later by a check that
    names another cause (the stance foot, the coordinate convention, the fit).

    Parameters
    ----------
    t : array_like
        (N,) times.
    q, dq : array_like
        (n, N) angles and their rates, one row per coordinate.
    names : sequence of str
        The coordinates' names (the file's column names), for the message.
    where : str
        Names the source in messages.

    Raises
    ------
    ValueError
        One line naming the coordinate, its range or the ratio, and the likely unit.
    """
    _check_radians(q, names, where)
    _check_rates(t, q, dq, names, where)


def _check_radians(q, names, where: str) -> None:
    """Angles in degrees (:func:`check_units`): one that turns by more than a full turn
    over the step, or that lies beyond one, or beyond a half turn where the others lie
    within it.

    No joint or link of a walking robot turns by 2 pi or more within one step; angles
    written in degrees do (a swing of 0.11 rad is 6.3 degrees), and would otherwise be
    refused later by a check that names another cause (the stance foot, the coordinate
    convention).  One angle logged in degrees beside the others in radians (a base pitch
    of 5 to 30 degrees) may turn by less, with its rate in degrees too (so that the rate
    check passes): no angle in radians needs a value beyond 2 pi, and a value beyond
    :data:`HALF_TURN_BEYOND` where every other angle stays within :data:`HALF_TURN_WITHIN`
    (the joints of a URDF whose zero pose folds them by a half turn reach pi and a little
    more) is one in degrees.
    """
    q = np.asarray(q, dtype=float)
    span = np.ptp(q, axis=1)
    i = int(np.argmax(span))
    if span[i] > 2 * np.pi + 1e-6:          # wrapped to [-pi, pi] spans 2 pi at most
        raise ValueError(f"{where}: {names[i]} spans {span[i]:.4g} over the step, more than "
                         f"a full turn (2 pi): angles in degrees? (a step is given in rad and "
                         f"rad/s)")
    reach = np.max(np.abs(q), axis=1)
    i = int(np.argmax(reach))
    others = float(np.max(np.delete(reach, i))) if reach.size > 1 else 0.0
    if reach[i] > 2 * np.pi + 1e-6:
        beyond = "beyond a full turn (2 pi)"
    elif reach[i] > HALF_TURN_BEYOND and others <= HALF_TURN_WITHIN:
        beyond = f"beyond a half turn where the other angles stay within {others:.3g}"
    else:
        return
    raise ValueError(f"{where}: {names[i]} goes from {q[i].min():.4g} to {q[i].max():.4g}, "
                     f"{beyond}: in degrees? (convert it and its rate to radians, x pi/180; "
                     f"a step is given in rad and rad/s)")


def _check_rates(t, q, dq, names, where: str) -> None:
    """Rates that do not integrate to the angles (:func:`check_units`; t in ms, rates in
    deg/s).

    Over the step, each coordinate's total change sum |q[k+1] - q[k]| is compared with
    what its rate integrates to over t (trapezoids, the same sum of magnitudes): the two
    agree to a few per cent for any sampling a step is given with (within 30 % at 5
    nodes), and differ by 1000 when t is in ms, by 57 when a rate is in deg/s beside its
    angle in rad.  Coordinates that move less than 0.05 rad either way are not compared.
    """
    t, q, dq = (np.asarray(a, dtype=float) for a in (t, q, dq))
    change = np.sum(np.abs(np.diff(q, axis=1)), axis=1)
    integral = np.sum(np.abs(0.5 * (dq[:, 1:] + dq[:, :-1]) * np.diff(t)), axis=1)
    moving = (change > 0.05) | (integral > 0.05)
    if not np.any(moving):
        return                                   # a robot standing still: nothing to compare
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(moving, change / integral, 1.0)
    off = np.where(moving, np.abs(np.log(np.maximum(ratio, 1e-300))), 0.0)
    i = int(np.argmax(off))
    if not 1.0 / RATE_RATIO <= ratio[i] <= RATE_RATIO:
        raise ValueError(f"{where}: {names[i]} changes {ratio[i]:.3g} times what its rate "
                         f"integrates to over t: t in ms, or rates in other units (deg/s)? "
                         f"(a step is given in s, rad and rad/s)")
    _check_time_scale(ratio[moving], where)


def _check_time_scale(ratio, where: str) -> None:
    """Every moving coordinate changing one and the same factor times what its rate
    integrates to, beyond :data:`COMMON_RATIO`: the times and the rates disagree (t
    scaled, the rates left as they were).

    Honest samplings differ from 1 coordinate by coordinate (a step resampled at 5 to 20
    nodes with noise: 0.2 to 2.3), and where they agree within :data:`COMMON_SPREAD`
    their common factor stays within 1.07; t doubled gives 0.500 on every coordinate.
    One moving coordinate alone is not evidence of a common factor.
    """
    if ratio.size < 2 or ratio.max() / ratio.min() > COMMON_SPREAD:
        return
    common = float(np.exp(np.mean(np.log(ratio))))
    if 1.0 / COMMON_RATIO <= common <= COMMON_RATIO:
        return
    raise ValueError(f"{where}: every coordinate changes {common:.3g} times what its rate "
                     f"integrates to over t ({ratio.min():.3g} to {ratio.max():.3g}): t and "
                     f"the rates are on different time scales, by a factor {1 / common:.3g} "
                     f"(t scaled, the rates not?) (a step is given in s, rad and rad/s)")


def relative_angles(nodes: Nodes) -> Nodes:
    """Nodes in absolute link angles phi converted to relative joint angles q.

    q_1 = phi_1, q_i = phi_i - phi_{i-1} (and the same for the rates); the inverse of
    the cumulative sums of docs/theory.md.

    Parameters
    ----------
    nodes : Nodes
        phi, dphi, ddphi.

    Returns
    -------
    Nodes
    """
    def rel(a):
        return None if a is None else np.vstack([a[:1], np.diff(a, axis=0)])
    return Nodes(nodes.t, rel(nodes.q), rel(nodes.dq), rel(nodes.ddq), nodes.source)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def csv_table(text: str, where: str, columns: str = "") -> tuple:
    """A CSV of numbers: its header and its rows.

    Parameters
    ----------
    text : str
        The file's text (blank lines skipped; a separator that ends every line, the
        header's too, makes no column).
    where : str
        Names the file in messages.
    columns : str
        The header expected, for the message on a file without one.

    Returns
    -------
    tuple
        (header: list of the names as written, stripped; values: (rows, columns) array).

    Raises
    ------
    ValueError
        Naming ``where``: empty, no header line, separated by ';' or tabs, a row of
        another length, a value that is not a number or is NaN or infinite.
    """
    reader = csv.reader(io.StringIO(text))
    rows, lines = [], []                   # the rows, and the file's line of each
    try:
        for r in reader:
            if r and any(c.strip() for c in r):
                rows.append(r)
                lines.append(reader.line_num)
    except csv.Error as e:                 # a stray carriage return, a NUL: not a CSV table
        why = str(e).split(" - ")[0]       # csv's advice on newline modes does not apply
        raise ValueError(f"{where}: not a CSV table (line {reader.line_num}: {why})") from None
    if not rows:
        raise ValueError(f"{where} is empty")
    while len(rows[0]) > 1 and all(len(r) == len(rows[0]) and not r[-1].strip() for r in rows):
        rows = [r[:-1] for r in rows]        # a separator ending every line: no column
    head = [c.strip() for c in rows[0]]
    if all(_is_number(c) for c in head):
        raise ValueError(f"{where}: no header line: line {lines[0]} holds numbers, not the "
                         f"column names" + (f" ({columns})" if columns else ""))
    if len(head) == 1:
        seps = {";": "';'", "\t": "tabs"}
        used = [name for sep, name in seps.items() if sep in head[0]]
        if used:
            raise ValueError(f"{where}: the header is one column: values must be separated "
                             f"by commas (this file uses {used[0]})")
    data = []
    for i, r in zip(lines[1:], rows[1:]):
        if len(r) != len(head):
            raise ValueError(f"{where}: line {i} has {len(r)} values, the header {len(head)}")
        try:
            data.append([float(c) for c in r])
        except ValueError:
            k, c = next((k, c) for k, c in enumerate(r) if not _is_number(c))
            raise ValueError(f"{where}: line {i} has a value that is not a number: {c.strip()!r} "
                             f"in column {head[k] or k + 1}") from None
        bad = [k for k, v in enumerate(data[-1]) if not np.isfinite(v)]
        if bad:                            # named here: the arrays do not know the columns
            raise ValueError(f"{where}: line {i}: column {head[bad[0]] or bad[0] + 1} has a "
                             f"NaN or infinite value: {r[bad[0]].strip()!r}")
    return head, np.array(data, dtype=float).reshape(-1, len(head))


def _read_csv(text: str, where: str, nq: int | None) -> Nodes:
    raw, a = csv_table(text, where, "t,q1..qn,dq1..dqn[,ddq1..ddqn]")
    head = [c.lower() for c in raw]
    h = len(head) - 1
    with_acc = h % 3 == 0 and head[-1].startswith("ddq")
    n = h // 3 if with_acc else h // 2
    want = ["t"] + [f"q{i}" for i in range(1, n + 1)] + [f"dq{i}" for i in range(1, n + 1)]
    if with_acc:
        want += [f"ddq{i}" for i in range(1, n + 1)]
    if n < 1 or head != want:
        hint = ("; a step in URDF angles? (--angles urdf --stance HIP_JOINT)"
                if "pitch" in head else "")
        raise ValueError(f"{where}: the header must be t,q1..qn,dq1..dqn[,ddq1..ddqn], got "
                         f"{','.join(raw)[:120]!r}{hint}")
    return nodes_from_arrays(a[:, 0], a[:, 1:1 + n], a[:, 1 + n:1 + 2 * n],
                             a[:, 1 + 2 * n:] if with_acc else None, nq, where)


def read_nodes(path, nq: int | None = None):
    """The nodes (or the virtual-constraint record) of a file.

    Parameters
    ----------
    path : str or Path
        ``.csv``, ``.npz`` or ``.json`` (module docstring).
    nq : int, optional
        The robot's number of coordinates (checked when given).

    Returns
    -------
    Nodes or dict
        The nodes; for a JSON file holding ``virtual_constraints`` that record (read by
        :func:`gait_opt.import_gait`).

    Raises
    ------
    ValueError
        Naming the file: missing, another suffix, unparsable, or nodes that are not
        valid (:func:`nodes_from_arrays`).

    Notes
    -----
    One step, from just after an impact to just before the next; s, rad, rad/s,
    rad/s^2; at least :data:`MIN_NODES` nodes, times strictly increasing, not
    necessarily uniform:

    - CSV: header ``t,q1,...,qn,dq1,...,dqn`` (optionally ``,ddq1,...,ddqn``), one row
      per node;
    - NPZ or JSON: arrays ``t`` (N,), ``q``, ``dq`` (N, n) and optionally ``ddq``;
    - JSON ``{"virtual_constraints": {"bezier": [[...], ...], "theta_plus": ...,
      "theta_minus": ..., "phase": [...], "outputs": [[...], ...]}}``: Bezier
      coefficients of h_d (one row per output) over s = (theta - theta^+) / (theta^- -
      theta^+), theta = phase . q, outputs H0 (optional, default the actuated joints).
    """
    path = file_path(path)
    where = f"gait file {path}"
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".npz", ".json"):
        raise ValueError(f"{where}: must end in .csv, .npz or .json")
    if suffix == ".npz":
        if not path.is_file():
            raise ValueError(f"{where}: not found (or not a file)")
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
            raise ValueError(f"{where}: cannot read the NPZ file ({e})") from None
        return _from_mapping(arrays, where, nq)
    text = read_text_file(path, "gait file", 50_000_000)
    if suffix == ".csv":
        return _read_csv(text, where, nq)
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as e:
        raise ValueError(f"{where}: not valid JSON ({e})") from None
    if isinstance(data, dict) and "virtual_constraints" in data:
        return data["virtual_constraints"]
    return _from_mapping(data, where, nq)


def _from_mapping(data, where: str, nq):
    if not isinstance(data, dict):
        raise ValueError(f"{where}: must hold arrays t, q, dq (and optionally ddq)")
    missing = [k for k in ("t", "q", "dq") if k not in data]
    if missing:
        raise ValueError(f"{where}: missing array(s) {', '.join(missing)} (t, q, dq and "
                         f"optionally ddq)")
    return nodes_from_arrays(data["t"], data["q"], data["dq"], data.get("ddq"), nq, where)
