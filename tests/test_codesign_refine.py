"""The local search's pool of starts (analysis.design.codesign.refine.Pool): which starts
it draws around and the best s* that meets the target's step."""
from __future__ import annotations

import math

import numpy as np

from analysis.design.codesign.refine import Pool


def _pool():
    # four starts: (s*, convergence step); start 2 converges by step 5 with the best s*
    M = np.arange(8.0).reshape(4, 2)
    return Pool(M, s_star=[1.5, 0.9, 1.2, 0.4], s_fail=[1.6, 1.0, 1.3, 0.5],
                cause=["torque"] * 4, frac=[0.9, 0.8, 0.7, 0.6],
                conv=[8, 4, 5, math.inf], sources=["sample"] * 4)


def test_best_target_counts_only_starts_that_converge_in_time():
    p = _pool()
    assert p.best_target(5) == 1.2            # s* 1.5 converges only at step 8
    assert p.best_target(8) == 1.5
    assert p.best_target(3) == 0.0            # none by step 3


def test_elite_puts_starts_converging_in_time_first_best_s_star_first():
    p = _pool()
    np.testing.assert_array_equal(p.elite(4, 5), p.M[[2, 1, 0, 3]])
    np.testing.assert_array_equal(p.elite(1, 5), p.M[[2]])
    # none in time: the soonest first
    np.testing.assert_array_equal(p.elite(2, 3), p.M[[1, 2]])


def test_add_appends_the_screens_figures():
    p = _pool()
    p.add(np.array([[9.0, 9.0]]), ([2.0], [2.1], ["friction"], [1.0], [3]), "refined")
    assert p.M.shape == (5, 2) and p.sources[-1] == "refined" and p.cause[-1] == "friction"
    assert p.best_target(5) == 2.0
    np.testing.assert_array_equal(p.elite(1, 5), [[9.0, 9.0]])
