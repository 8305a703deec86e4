"""The least-squares fit of MuJoCo's running stride map (fit_running_map) against a known
linear map: its bias at a few hundred noisy strides, and the calibration against a
reference map that measures it (no MuJoCo run: synthetic landing states)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from biped_casadi.mujoco.running_records import (MujocoRun, RunningStride, fit_running_map,
                                                 reference_fit)


def _map(n=10, radius=0.4, seed=3):
    """A stable n x n map with a dominant complex pair of modulus ``radius``."""
    rng = np.random.default_rng(seed)
    V = rng.normal(size=(n, n))
    D = np.diag(rng.uniform(-0.3, 0.3, n) * radius / 0.3)
    th = 0.667
    D[:2, :2] = radius * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    return V @ D @ np.linalg.inv(V)


def _run(A, strides=300, rank=3, scale=0.1, seed=0):
    """A MujocoRun whose landing states follow x_{k+1} = A x_k + e_k, the noise in
    ``rank`` directions (MuJoCo's jitter excites few)."""
    rng = np.random.default_rng(seed)
    n = A.shape[0]
    B = rng.normal(size=(n, rank))
    x = [np.zeros(n)]
    for _ in range(strides):
        x.append(A @ x[-1] + scale * B @ rng.normal(size=rank))
    recs = [RunningStride(index=i, t_landing=0.0, stance=0.35, flight=0.1, step_length=0.7,
                          speed=1.5, landing_state=list(v), deviation=0.0, peak_torque=0.0,
                          clipped_time=0.0, slip=0.0, fz_max=0.0)
            for i, v in enumerate(x[1:])]
    return MujocoRun(status="ran", message="", n_strides=strides, strides=recs,
                     start=list(x[0]), fixed_point=[0.0] * n, deviations=[], gait={},
                     controller={}, settings={}, torque_limit=150.0, mujoco_steps=0,
                     wall_time=0.0)


def test_fit_of_a_known_map_is_biased_and_the_reference_measures_it():
    A = _map()
    true = float(np.max(np.abs(np.linalg.eigvals(A))))
    f = fit_running_map(_run(A), reference=A)
    assert f.status == "ok" and math.isclose(f.reference_radius, true, rel_tol=1e-12)
    # the fit of the true map reports more than its radius, and the calibration
    # (the same fit on runs of the reference) agrees with it
    assert f.max_abs > true + 0.05
    assert f.reference_max_abs > true + 0.05 and f.reference_max_abs_spread > 0
    assert abs(f.max_abs - f.reference_max_abs) < 3 * max(f.reference_max_abs_spread,
                                                          f.max_abs_spread)
    assert "reference map" in f.message
    json.dumps(f.to_dict(), allow_nan=False)


def test_full_rank_noise_and_a_longer_run_shrink_the_bias():
    A = _map()
    true = float(np.max(np.abs(np.linalg.eigvals(A))))
    short = fit_running_map(_run(A))
    f = fit_running_map(_run(A, strides=1000, rank=10))
    assert abs(f.max_abs - true) < 0.1 and f.max_abs - true < short.max_abs - true
    assert math.isnan(f.reference_max_abs) and math.isnan(f.reference_radius)


def test_reference_fit_of_a_zero_map_and_bad_reference():
    rng = np.random.default_rng(0)
    m, s = reference_fit(np.zeros((2, 2)), rng.normal(size=(50, 2)), [200], rng, replicas=20)
    assert 0 < m < 0.3 and s > 0
    with pytest.raises(ValueError, match="reference"):
        fit_running_map(_run(_map()), reference=np.eye(3))
