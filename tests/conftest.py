"""Shared fixtures: the robot model is built once per session, the reference gait once
per session and cached on disk between sessions (keyed by robot and options)."""
from __future__ import annotations

import os

import numpy as np
import pytest

from biped_casadi import rabbit

# tasks run in the test process unless a test asks for a cluster (analysis.tasks: the
# scheduler's default); the tests of the cluster paths start their own
os.environ.setdefault("BIPED_SCHEDULER", "synchronous")


@pytest.fixture(scope="session")
def model():
    return rabbit()


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def gait(model):
    """The default reference gait (SPEC section 2), from the on-disk cache
    ($BIPED_CACHE_DIR or ~/.cache/biped-casadi): solved at most once per machine."""
    from gait_opt import optimize_gait
    return optimize_gait(model, cache=True)


@pytest.fixture(scope="session")
def model3():
    """The three-link biped of Grizzle, Abba & Plestan (2001), a built-in description."""
    from biped_casadi import robot
    return robot("three_link")


@pytest.fixture(scope="session")
def gait3(model3):
    """Its default reference gait (the same problem as RABBIT's, the robot's torque
    limit), from the on-disk cache."""
    from gait_opt import optimize_gait
    return optimize_gait(model3, cache=True)


@pytest.fixture(scope="session")
def running_gait(model):
    """RABBIT's running step at 1.5 m/s on the default grid, from the on-disk cache
    (solved at most once per machine; shared by the running tests)."""
    from gait_opt.running import RunningOptions, optimize_running
    g = optimize_running(model, RunningOptions(speed=1.5), cache=True)
    assert g.success
    return g


@pytest.fixture(scope="session")
def running_cycle15(model, running_gait):
    """Its stride map under the how-to's design (PD Kp 400 N m/rad, Kd 30 N m s/rad,
    M1 = (0, 0.95, 0.95, 0)), built once per session (other gains: ``retuned``)."""
    from analysis.stability.running_cycle import running_cycle
    from biped_casadi.control.running import RunningController
    return running_cycle(RunningController(model, running_gait, 400.0, 30.0,
                                           M1=(0.0, 0.95, 0.95, 0.0)))
