"""Shared fixtures: the robot model is built once per session, the reference gait once
per session and cached on disk between sessions (keyed by robot and options)."""
from __future__ import annotations

import numpy as np
import pytest

from biped_casadi import rabbit


@pytest.fixture(scope="session")
def model():
    return rabbit()


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
