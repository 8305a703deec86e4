"""What a reproduction computes (its resolution) and where it writes (its folder)."""
from __future__ import annotations

import re
from dataclasses import dataclass, fields
from pathlib import Path, PurePath

import numpy as np

from biped_casadi import RABBIT_DESCRIPTION, robot
from biped_casadi.numerics import as_count, as_number

from ..design.codesign import FULL, QUICK, CodesignSettings
from ..robustness import RobustnessSettings

__all__ = ["Resolution", "ReproduceOptions", "run_folder"]


@dataclass(frozen=True)
class Resolution:
    """What every stage computes at which resolution (what the numbers depend on).

    The full run's settings by default, the quick run's from :meth:`make`.

    Parameters
    ----------
    quick : bool
        Whether these are the quick run's settings (its folder and report).
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
    nlp_random : int
        Random starts of the M1 NLP besides the grid's best points.
    sim_steps : int
        Steps of the full-order runs of Fig. 5 and 6.
    animation_steps : int
        Steps in the animation (0: none).
    robustness : RobustnessSettings
        How s* is measured (directions, bisection rounds) by the walking stages.
    basin_n : int
        Points per side of the basins' grids.
    codesign : CodesignSettings
        The robust co-design (the gait co-designed in the full run, fixed in the quick).
    terrain_sigmas : tuple of float
        Uneven ground: the sigmas of the MFPT curves, m.
    terrain_runs, terrain_steps : int
        Uneven ground: runs of each Monte Carlo and their steps.
    terrain_error_runs : int
        Uneven ground: runs of each model-error Monte Carlo.
    gsn_every_design : bool
        The gait sensitivity norm of every time-varying design (else of the last).
    mujoco_steps, mujoco_scale_steps : int
        In MuJoCo: the steps of each walk, and of each walk from a scaled perturbation.
    mujoco_scales : tuple of float
        In MuJoCo: the scales of the paper's perturbation tried.
    mujoco_directions : int
        In MuJoCo: the perturbation directions of the stride map.
    """

    quick: bool = False
    line_points: int = 401
    grid_n: int = 9
    plane_n: int = 161
    domain_n: int = 81
    domain_range: tuple = (-10.0, 10.0)
    nlp_starts: int = 10
    nlp_random: int = 2
    sim_steps: int = 10
    animation_steps: int = 4
    robustness: RobustnessSettings = RobustnessSettings()
    basin_n: int = 101
    codesign: CodesignSettings = FULL
    terrain_sigmas: tuple = (0.002, 0.004, 0.008, 0.012)
    terrain_runs: int = 32
    terrain_steps: int = 20
    terrain_error_runs: int = 12
    gsn_every_design: bool = True
    mujoco_steps: int = 100
    mujoco_scale_steps: int = 30
    mujoco_scales: tuple = (1, 2, 3, 4, 6, 8)
    mujoco_directions: int = 16

    def __post_init__(self):
        """Each field checked as it is given (ValueError naming it), not when a stage
        first uses it."""
        lows = dict(line_points=2, grid_n=2, plane_n=2, domain_n=2, nlp_starts=1,
                    nlp_random=0, sim_steps=1, animation_steps=0, basin_n=2, terrain_runs=1,
                    terrain_steps=1, terrain_error_runs=1, mujoco_steps=1,
                    mujoco_scale_steps=1, mujoco_directions=1)
        for name, low in lows.items():
            object.__setattr__(self, name, as_count(getattr(self, name), name, low))
        for name in ("quick", "gsn_every_design"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        for name, kind in (("robustness", RobustnessSettings), ("codesign", CodesignSettings)):
            if not isinstance(getattr(self, name), kind):
                raise ValueError(f"{name} must be a {kind.__name__}, got "
                                 f"{type(getattr(self, name)).__name__}")
        for name in ("terrain_sigmas", "mujoco_scales", "domain_range"):
            v = getattr(self, name)
            v = tuple(v) if isinstance(v, (list, tuple, np.ndarray)) else v
            if not isinstance(v, tuple) or not v:
                raise ValueError(f"{name} must be a non-empty tuple of numbers, got {v!r}")
            for i, x in enumerate(v):
                as_number(x, f"{name}[{i}]", positive=name != "domain_range")
            object.__setattr__(self, name, v)
        lo_hi = self.domain_range
        if len(lo_hi) != 2 or not lo_hi[0] < lo_hi[1]:
            raise ValueError(f"domain_range must be (low, high) with low < high, got {lo_hi!r}")

    @classmethod
    def make(cls, quick: bool = False, **kw) -> "Resolution":
        """The full or the quick resolution, with some fields changed.

        Parameters
        ----------
        quick : bool
            The quick run's settings: coarser grids, fewer starts, directions and runs,
            the co-design's gait fixed.
        **kw
            Fields to change.

        Returns
        -------
        Resolution
        """
        base = dict(quick=True, line_points=101, domain_n=41, plane_n=81, nlp_starts=4,
                    nlp_random=0, sim_steps=6, animation_steps=2,
                    robustness=RobustnessSettings(directions=8, rounds=6), basin_n=41,
                    codesign=QUICK, terrain_sigmas=(0.004, 0.008), terrain_runs=16,
                    terrain_steps=12, terrain_error_runs=6, gsn_every_design=False,
                    mujoco_steps=30, mujoco_scales=(1, 2, 3), mujoco_directions=8) \
            if quick else {}
        base.update(kw)
        return cls(**base)

    def to_dict(self) -> dict:
        """The fields in JSON types (the settings as their dictionaries).

        Returns
        -------
        dict
        """
        return {f.name: (v.to_dict() if hasattr(v, "to_dict") else dict(v.__dict__)
                         if hasattr(v, "__dataclass_fields__") else v)
                for f in fields(self) for v in (getattr(self, f.name),)}


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

    def __post_init__(self):
        """The fields checked as they are given (ValueError naming one); the robot and
        the scheduler where they are resolved."""
        for name in ("quick", "progress"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if not isinstance(self.robot, (str, PurePath)) or not str(self.robot).strip():
            raise ValueError(f"robot must be a robot's name or a description file, got "
                             f"{self.robot!r}")
        if self.workers is not None:
            object.__setattr__(self, "workers", as_count(self.workers, "workers", 1))
        if self.resolution is not None:
            if not isinstance(self.resolution, dict):
                raise ValueError(f"resolution must be a dict of Resolution fields, got "
                                 f"{type(self.resolution).__name__}")
            bad = set(self.resolution) - {f.name for f in fields(Resolution)}
            if bad:
                raise ValueError(f"reproduce: unknown option {sorted(bad)[0]!r}")
        self.resolution_of()                    # its fields checked now

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
