"""What a sweep computes: the settings and the result (status, max|lambda|, eigenvalues
and A^z per point)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from biped_casadi.results import Result, internal

from ..stability.poincare import STATUSES


__all__ = ["SweepSettings", "SweepResult", "BestPoint", "RESULTS_VERSION", "METHODS"]


#: bump when a change in analysis/ alters the numbers computed for the same settings,
#: so that folders written before are refused instead of mixed (besides the code
#: digest, ``code_version('sweep')``, which is part of a folder's identity too)
RESULTS_VERSION = 1
#: how A^z is computed (SweepSettings.method)
METHODS = ("variational", "ad")


@dataclass(frozen=True)
class SweepSettings:
    """How each M1 of a sweep is evaluated.

    Parameters
    ----------
    method : {'variational', 'ad'}
        'variational' (the batched variational equation, the sweep path) or 'ad' (full
        AD through the discrete map, ~1000x slower).
    n_pre, n_post, n_scan : int
        RK4 steps from the section to the impact and back, and of the impact scan
        (options of :class:`analysis.PoincareMap`).
    horizon : float
        The swing foot must strike before ``horizon`` T (> 1).
    """
    method: str = "variational"
    n_pre: int = 80
    n_post: int = 240
    n_scan: int = 250
    horizon: float = 2.0

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"settings.method must be one of {METHODS}, got {self.method!r}")
        for name in ("n_pre", "n_post", "n_scan"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
                raise ValueError(f"settings.{name} must be a positive integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        if not (isinstance(self.horizon, (int, float)) and math.isfinite(self.horizon)
                and self.horizon > 1):
            raise ValueError(f"settings.horizon must be a number > 1 (in steps T), "
                             f"got {self.horizon!r}")
        object.__setattr__(self, "horizon", float(self.horizon))

    def to_dict(self) -> dict:
        """The settings by name, as stored in a sweep folder.

        Returns
        -------
        dict
            ``method``, ``n_pre``, ``n_post``, ``n_scan``, ``horizon``.
        """
        return dict(method=self.method, n_pre=self.n_pre, n_post=self.n_post,
                    n_scan=self.n_scan, horizon=self.horizon)

    def map_options(self) -> dict:
        """The keyword arguments of :func:`analysis.poincare_map` these settings give.

        Returns
        -------
        dict
            ``n_pre``, ``n_post``, ``n_scan``, ``horizon``.
        """
        return dict(n_pre=self.n_pre, n_post=self.n_post, n_scan=self.n_scan,
                    horizon=self.horizon)


@dataclass
class BestPoint:
    """The point of a sweep with the smallest finite max ``|lambda|``.

    Parameters
    ----------
    M1 : numpy.ndarray
        (nu,) its outputs.
    max_abs : float
        Its max ``|lambda|``.
    status : str
        Its status ('stable', 'unstable', or 'open_orbit' on a gait that is not an orbit).
    """

    M1: np.ndarray
    max_abs: float
    status: str


@dataclass
class SweepResult(Result):
    """Results of a sweep, row i for ``points[i]``.

    ``status`` is 'complete' (every point has its result; ``success``).  The per-point
    arrays are left out of ``to_dict()``.

    Parameters
    ----------
    counts : dict
        Number of points per status of docs: theory §4.
    elapsed : float
        This run's wall time, s.
    chunk_size : int
        Points per chunk.
    settings : dict
        Everything that identifies the sweep (code and gait digests, robot, points'
        digest, map settings), as stored in its folder.
    out_dir : Path or None
        The results folder (None: in memory only).
    computed_chunks : list of int
        Chunks evaluated by this run.
    reused_chunks : list of int
        Chunks read back from ``out_dir``.
    corrupt_chunks : dict
        Chunk -> reason, for chunks found damaged and recomputed.
    n_computed : int
        Points evaluated by this run.
    status : str
        'complete'.
    message : str
        Empty for a complete sweep.
    points : numpy.ndarray
        (n, nu) the M1 of the sweep.
    point_status : numpy.ndarray
        (n,) strings of docs: theory §4.
    max_abs : numpy.ndarray
        (n,) max ``|lambda|``, inf where singular or without impact.
    eigenvalues : numpy.ndarray
        (n, 2) complex, ``|.|`` descending, NaN where undefined.
    A : numpy.ndarray
        (n, 2, 2) the Jacobians A^z.
    """
    counts: dict
    elapsed: float
    chunk_size: int
    settings: dict = internal()
    out_dir: Path | None = None
    computed_chunks: list = field(default_factory=list)
    reused_chunks: list = field(default_factory=list)
    corrupt_chunks: dict = field(default_factory=dict)
    n_computed: int = 0
    status: str = "complete"
    message: str = ""
    points: np.ndarray = internal(default=None)
    point_status: np.ndarray = internal(default=None)
    max_abs: np.ndarray = internal(default=None)
    eigenvalues: np.ndarray = internal(default=None)
    A: np.ndarray = internal(default=None)

    SUCCESS = ("complete",)

    @property
    def n_points(self) -> int:
        """Number of M1 in the sweep."""
        return len(self.points)

    def best(self) -> "BestPoint | None":
        """The M1 of the sweep with the smallest finite max ``|lambda|``.

        Returns
        -------
        BestPoint or None
            None when no point has a finite value.
        """
        finite = np.isfinite(self.max_abs)
        if not finite.any():
            return None
        i = int(np.flatnonzero(finite)[np.argmin(self.max_abs[finite])])
        return BestPoint(self.points[i].copy(), float(self.max_abs[i]), str(self.point_status[i]))

    def to_dict(self) -> dict:
        """Counts, timing, storage and the best point (the JSON of ``biped sweep``).

        Returns
        -------
        dict
            The fields of :meth:`Result.to_dict` (without the per-point arrays), plus
            ``n_points``, ``best`` (``M1`` and ``max_abs``, or None),
            ``computed_points`` and ``reused_points``.
        """
        b = self.best()
        return dict(super().to_dict(), n_points=self.n_points,
                    best=None if b is None else dict(M1=b.M1.tolist(), max_abs=b.max_abs),
                    computed_points=self.n_computed,
                    reused_points=self.n_points - self.n_computed)

    def subset(self, rows) -> "SweepResult":
        """Some rows as a sweep result of their own.

        Parameters
        ----------
        rows : array_like
            Row indices or a boolean mask over the points.

        Returns
        -------
        SweepResult
            With counts of those rows only.
        """
        rows = np.asarray(rows)
        st = self.point_status[rows]
        return _result(self.points[rows], st, self.max_abs[rows], self.eigenvalues[rows],
                       self.A[rows], elapsed=self.elapsed, chunk_size=self.chunk_size,
                       settings=self.settings, out_dir=self.out_dir)


def _result(P, st, max_abs, ev, A, **kw) -> SweepResult:
    return SweepResult(counts=_counts(st), points=P, point_status=st, max_abs=max_abs,
                       eigenvalues=ev, A=A, **kw)



def _counts(status) -> dict:
    return {s: int(np.count_nonzero(status == s)) for s in STATUSES}


