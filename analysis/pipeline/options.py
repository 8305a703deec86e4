"""What a reproduction computes (its resolution) and where it writes (its folder)."""
from __future__ import annotations

import re
from dataclasses import dataclass, fields
from pathlib import Path

from biped_casadi import RABBIT_DESCRIPTION, robot

__all__ = ["Resolution", "ReproduceOptions", "run_folder"]


@dataclass(frozen=True)
class Resolution:
    """The resolution of every stage (what the numbers depend on).

    Parameters
    ----------
    quick : bool
        The coarse variant: fewer points and starts, the co-design's gait fixed.
    line_points : int
        Fig. 2: points per component on [-10, 10].
    grid_n : int
        The M1 grid's points per component (the paper's 9^4).
    plane_n : int
        Two torques: the (M1(1), M1(2)) grid, points per side.
    domain_n : int
        Fig. 4: (M1(2), M1(3)) grid per group.
    domain_range : tuple
        Fig. 4's range of both components.
    nlp_starts : int
        Starts of the M1 NLP.
    sim_steps : int
        Steps of the full-order runs of Fig. 5 and 6.
    animation_steps : int
        Steps in the animation.
    """

    quick: bool = False
    line_points: int = 401
    grid_n: int = 9
    plane_n: int = 161
    domain_n: int = 81
    domain_range: tuple = (-10.0, 10.0)
    nlp_starts: int = 10
    sim_steps: int = 10
    animation_steps: int = 4

    @classmethod
    def make(cls, quick: bool = False, **kw) -> "Resolution":
        """The full or the quick resolution, with some fields changed.

        Parameters
        ----------
        quick : bool
            The coarse variant.
        **kw
            Fields to change.

        Returns
        -------
        Resolution
        """
        base = dict(quick=True, line_points=101, domain_n=41, plane_n=81, nlp_starts=4,
                    sim_steps=6, animation_steps=2) if quick else {}
        base.update(kw)
        return cls(**base)


@dataclass
class ReproduceOptions:
    """A reproduction: its robot, resolution and where it runs.

    Parameters
    ----------
    quick : bool
        The coarse variant (:meth:`Resolution.make`).
    robot : str
        A built-in robot or a description file (default RABBIT).
    progress : bool
        A line per stage and a bar of finished tasks on stderr.
    scheduler : str or Client, optional
        Where the tasks run (:func:`analysis.tasks.resolve_scheduler`).
    workers : int, optional
        Processes of a local cluster (1: this process).
    resolution : dict
        Fields of :class:`Resolution` to change.
    """

    quick: bool = False
    robot: str = "rabbit"
    progress: bool = True
    scheduler: object = None
    workers: int | None = None
    resolution: dict = None

    @classmethod
    def make(cls, quick: bool = False, **kw) -> "ReproduceOptions":
        """Options from keyword arguments; fields of :class:`Resolution` are accepted too.

        Parameters
        ----------
        quick : bool
            The coarse variant.
        **kw
            Fields of this class or of :class:`Resolution`.

        Returns
        -------
        ReproduceOptions
        """
        own = {f.name for f in fields(cls)}
        res = {f.name for f in fields(Resolution)}
        bad = set(kw) - own - res
        if bad:
            raise ValueError(f"reproduce: unknown option {sorted(bad)[0]!r}")
        mine = {k: v for k, v in kw.items() if k in own}
        mine["resolution"] = dict(mine.get("resolution") or {},
                                  **{k: v for k, v in kw.items() if k in res and k != "quick"})
        return cls(quick=quick, **mine)

    def resolution_of(self) -> Resolution:
        """The run's resolution.

        Returns
        -------
        Resolution
        """
        return Resolution.make(self.quick, **(self.resolution or {}))


def run_folder(out_dir, quick: bool, robot_name="rabbit") -> Path:
    """The folder a run writes into.

    ``out_dir`` for the full run on RABBIT, ``out_dir/quick`` for the quick one; for
    another robot ``out_dir/<name>`` and
    ``out_dir/<name>/quick``, the name being the built-in robot's or the description
    file's (``--robot my_biped.toml``: ``my_biped``).

    Parameters
    ----------
    out_dir : str or Path
        The output folder.
    quick : bool
        A quick run.
    robot_name : str or Path
        A built-in robot name or a description file (ValueError when unknown).

    Returns
    -------
    Path
    """
    folder = Path(out_dir)
    if robot(robot_name or "rabbit").description != RABBIT_DESCRIPTION:
        text = str(robot_name).strip()
        stem = Path(text).stem if Path(text).suffix.lower() in (".toml", ".json", ".urdf") \
            else text
        slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", stem).strip("._") or "robot"
        folder = folder / (f"robot_{slug}" if slug in ("quick", "figures", "sweeps")
                           else slug)
    return folder / "quick" if quick else folder
