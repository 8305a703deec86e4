"""Uneven ground: one ground height per step.

Step k ends where its swing foot strikes the ground at height h_k above the stance foot
of that step (h_k > 0 a step up, h_k < 0 a step down); the next step's stance foot is
there, so heights are relative, step to step, and a run over K steps meets the absolute
heights h_0, h_0 + h_1, ...  The footholds are blocks at their heights and the ground
between two footholds is at the lower one's level.  During step k the swing foot strikes
where it comes down through h_k in front of the stance foot (x_sw > 0; a foot that
passes the stance foot below a step up trips on it: it is under that ground); behind
the stance foot the ground is at min(0, -h_(k-1)), the lower of the previous foothold
(where the foot lifts off) and the stance foot's (0 before the first step).  Nothing
else changes: the impact is
rigid and instantaneous wherever it happens, every validity condition is the same,
measured from the ground under the foot (:func:`biped_casadi.simulation.kernel.strike`,
:func:`biped_casadi.simulation.validity.node_violations`), and every controller keeps
its meaning (the correction v_c of the time-varying controller still starts from the
outputs at each step start).

A terrain is an explicit list of heights (:class:`Terrain`), seeded random heights
i.i.d. N(0, sigma^2) (:meth:`Terrain.random`, :func:`random_heights` for many runs, run i
drawn from its own stream so that any subset of runs is reproducible on its own), or a
profile file (:meth:`Terrain.load`).  Past its last height a terrain is flat.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..files import write_text_atomic

__all__ = ["Terrain", "random_heights", "step_heights", "ground_levels", "MAX_HEIGHT",
           "TerrainFileError"]

#: the largest |h_k| a terrain may hold, m (a step of 20 cm is beyond any gait here)
MAX_HEIGHT = 0.2
#: the largest profile file read, bytes
MAX_FILE_BYTES = 10_000_000


class TerrainFileError(ValueError):
    """A terrain profile file that cannot be used (missing, unreadable or malformed)."""


def _check_heights(values, name: str = "heights") -> np.ndarray:
    try:
        h = np.asarray(values, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numbers (ground heights in m)") from None
    if not np.all(np.isfinite(h)):
        raise ValueError(f"{name} must be finite numbers")
    if h.size and np.max(np.abs(h)) > MAX_HEIGHT:
        raise ValueError(f"{name}: every |h| must be at most {MAX_HEIGHT} m, got "
                         f"{np.max(np.abs(h)):.4g} m")
    return h


@dataclass(frozen=True)
class Terrain:
    """Ground heights, one per step (module docstring).

    Parameters
    ----------
    heights : tuple of float
        h_k, m: where step k's swing foot strikes, above the stance foot of step k;
        flat (0) past the last one.
    """

    heights: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "heights", tuple(_check_heights(self.heights).tolist()))

    @classmethod
    def flat(cls) -> "Terrain":
        """Flat ground.

        Returns
        -------
        Terrain
        """
        return cls(())

    @classmethod
    def random(cls, sigma: float, steps: int, seed: int = 0, run: int = 0) -> "Terrain":
        """Heights i.i.d. N(0, sigma^2) of one run (row ``run`` of :func:`random_heights`).

        Parameters
        ----------
        sigma : float
            Standard deviation, m (>= 0).
        steps : int
            Heights drawn.
        seed : int
            Seed of the terrain.
        run : int
            Which run's stream.

        Returns
        -------
        Terrain
        """
        return cls(tuple(random_heights(sigma, steps, seed, [run])[0]))

    @classmethod
    def load(cls, path) -> "Terrain":
        """A terrain from a profile file.

        The file is a JSON list of heights (or ``{"heights": [...]}``), or text with one
        or more numbers per line (commas or spaces; ``#`` starts a comment).

        Parameters
        ----------
        path : str or Path
            The file, heights in m.

        Returns
        -------
        Terrain

        Raises
        ------
        TerrainFileError
            Missing, unreadable, empty or malformed, or a height out of range.
        """
        p = Path(path)
        try:
            if not p.is_file():
                raise TerrainFileError(f"terrain file not found (or not a file): {p}")
            if p.stat().st_size > MAX_FILE_BYTES:
                raise TerrainFileError(f"terrain file {p} is larger than "
                                       f"{MAX_FILE_BYTES // 1_000_000} MB")
            text = p.read_text()
        except UnicodeDecodeError:
            raise TerrainFileError(f"terrain file {p} is not text") from None
        except OSError as e:
            raise TerrainFileError(f"terrain file {p}: {e.strerror or e}") from None
        values = _parse_profile(text, p)
        if not values:
            raise TerrainFileError(f"terrain file {p} holds no height")
        try:
            return cls(tuple(values))
        except ValueError as e:
            raise TerrainFileError(f"terrain file {p}: {e}") from None

    def save(self, path):
        """Write the heights as a JSON profile file (readable by :meth:`load`), atomically.

        Parameters
        ----------
        path : str or Path
            The file.
        """
        write_text_atomic(path, json.dumps({"heights": list(self.heights)}) + "\n")

    def height(self, k: int) -> float:
        """h_k, m (0 past the last height).

        Parameters
        ----------
        k : int
            The step.

        Returns
        -------
        float
        """
        return float(self.heights[k]) if 0 <= k < len(self.heights) else 0.0

    def behind(self, k: int) -> float:
        """The ground behind the stance foot of step k, min(0, -h_(k-1)), m (0 for k = 0).

        Parameters
        ----------
        k : int
            The step.

        Returns
        -------
        float
        """
        return min(0.0, -self.height(k - 1)) if k > 0 else 0.0

    def __len__(self) -> int:
        return len(self.heights)

    def to_dict(self) -> dict:
        """The heights as a list.

        Returns
        -------
        dict
            ``heights``, m.
        """
        return dict(heights=list(self.heights))


def _parse_profile(text: str, path: Path) -> list:
    stripped = text.strip()
    if stripped.startswith("[") or stripped.startswith("{"):
        try:
            data = json.loads(stripped)
        except ValueError as e:
            raise TerrainFileError(f"terrain file {path}: malformed JSON ({e})") from None
        if isinstance(data, dict):
            data = data.get("heights")
        if not isinstance(data, list) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in data):
            raise TerrainFileError(f"terrain file {path}: expected a list of numbers "
                                   "(or {\"heights\": [...]})")
        return [float(v) for v in data]
    values = []
    for i, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].replace(",", " ").strip()
        for tok in line.split():
            try:
                values.append(float(tok))
            except ValueError:
                raise TerrainFileError(f"terrain file {path}, line {i}: {tok!r} is not a "
                                       "number") from None
    return values


def random_heights(sigma: float, steps: int, seed: int, runs) -> np.ndarray:
    """Heights i.i.d. N(0, sigma^2) of the runs ``runs``, each from its own stream.

    Run i's heights come from ``numpy.random.default_rng([seed, i])``, so they do not
    depend on which other runs are drawn, in what order or in what chunks.

    Parameters
    ----------
    sigma : float
        Standard deviation, m (>= 0, finite).
    steps : int
        Heights per run.
    seed : int
        Seed of the terrain.
    runs : array_like of int
        Run indices.

    Returns
    -------
    numpy.ndarray
        (len(runs), steps) heights, m, clipped to +-:data:`MAX_HEIGHT`.
    """
    if not (isinstance(sigma, (int, float)) and math.isfinite(sigma) and sigma >= 0):
        raise ValueError(f"sigma must be a finite number >= 0, got {sigma!r}")
    runs = np.atleast_1d(np.asarray(runs, dtype=np.int64))
    out = np.zeros((runs.size, int(steps)))
    if sigma == 0:
        return out
    for j, i in enumerate(runs):
        out[j] = np.random.default_rng([int(seed), int(i)]).standard_normal(int(steps))
    return np.clip(sigma * out, -MAX_HEIGHT, MAX_HEIGHT)


def step_heights(terrain, n: int, steps: int) -> np.ndarray:
    """The heights of n runs over ``steps`` steps, as an array.

    Parameters
    ----------
    terrain : None, Terrain, or array_like
        None: flat; a :class:`Terrain`: the same for every run; an array (n, >= steps)
        or (>= steps,): heights per run (or shared).

    n : int
        Runs.
    steps : int
        Steps.

    Returns
    -------
    numpy.ndarray
        (n, steps) heights h_k, m.
    """
    if terrain is None:
        return np.zeros((n, steps))
    if isinstance(terrain, Terrain):
        row = np.array([terrain.height(k) for k in range(steps)])
        return np.broadcast_to(row, (n, steps)).copy()
    h = _check_heights(terrain, "terrain").reshape(np.shape(terrain))
    h = np.atleast_2d(h)
    if h.shape[1] < steps:
        h = np.hstack([h, np.zeros((h.shape[0], steps - h.shape[1]))])
    h = h[:, :steps]
    if h.shape[0] not in (1, n):
        raise ValueError(f"terrain: {h.shape[0]} rows of heights for {n} runs")
    return np.broadcast_to(h, (n, steps)).copy()


def ground_levels(heights, k: int):
    """The ``ground`` of step k (kernel): (ahead, behind) = (h_k, min(0, -h_(k-1))).

    Parameters
    ----------
    heights : numpy.ndarray
        (n, steps) heights of n runs (:func:`step_heights`), or (steps,).
    k : int
        The step.

    Returns
    -------
    tuple of numpy.ndarray
        (ahead, behind), (n,) each (floats for one run), m.
    """
    h = np.asarray(heights, float)
    ahead = h[..., k]
    behind = np.minimum(0.0, -h[..., k - 1]) if k > 0 else np.zeros_like(ahead)
    return ahead, behind
