"""The feet of a running step above their bounds between the collocation points.

The cheap case: RABBIT at 1.5 m/s on 4 + 3 intervals with a swing-foot clearance of
0.2 m, which the swing foot rides in stance; its first solve passes 9.3e-5 m below the
clearance profile on the dense grid (1.0e-4 between its samples) between the first two
stance points."""
from __future__ import annotations

import numpy as np
import pytest

from biped_casadi import rabbit
from gait_opt.running import RunningOptions, optimize_running
from gait_opt.running_checks import check_running, dense

OPTIONS = dict(speed=1.5, n_stance=4, n_flight=3, clearance=0.2)


@pytest.fixture(scope="module")
def step():
    """(RABBIT, its coarse 1.5 m/s running step with the high clearance)."""
    m = rabbit()
    return m, optimize_running(m, RunningOptions(**OPTIONS))


def _clearance_margin(m, g):
    """Smallest height of the swing foot above the clearance profile in stance, on the
    checks' dense grid, m."""
    t, x, _ = dense(m, g, "stance")
    _, z = m.swing_foot.map(t.size)(x[:m.nq])
    s = t / g.T_stance
    return float(np.min(np.array(z).ravel() - g.options.clearance * 4 * s * (1 - s)))


def test_the_feet_keep_their_bounds_between_the_points(step):
    """Bounded on that interval and solved again, the swing foot stays above the
    profile on the dense grid, the feet above the ground in flight, and the re-solve
    says what it bounded."""
    m, g = step
    assert g.success
    assert _clearance_margin(m, g) >= -1e-7
    r = check_running(m, g)
    assert r.violations(150.0) == [] and r.feet_min_flight >= -1e-7
    passes = g.solver_stats["tightenings"]
    assert 1 <= len(passes) <= 3 and "failed" not in passes[-1]
    dip = passes[0]["dips"][0]
    assert dip["foot"] == "swing foot above the clearance profile in stance"
    assert dip["phase"] == "stance" and dip["interval"] == 0 and 0.5 < dip["s"] < 1.0
    assert 1e-5 < dip["depth"] < 1e-3
    assert max(passes[0]["excess"]) < 0                      # the torques within 150 N m


def test_the_loop_fixes_torques_and_feet_in_one_resolve():
    """A torque above its limit and a foot below its bound are fixed by the same
    re-solve; the points found are kept for the solves after it."""
    from gait_opt.running_solve import within_path_limits

    class Step:
        def __init__(self, peak):
            self.u_stance, self.u_flight = np.array([[0.0, peak, 0.0]]), np.zeros((1, 3))
            self.success = True
            self.solver_stats = dict(iterations=5, wall_s=1.0, success=True)
    calls, found = [], iter([[dict(depth=1e-4, s=0.3)], [dict(depth=2e-6, s=0.31)], []])

    def solve(guess, umax, points):
        calls.append((umax, points))
        return Step(60.05 if guess is None else 60.0)
    got = within_path_limits(solve, 60.0, lambda gait: next(found))
    assert [len(p) for _, p in calls] == [0, 1, 2]
    assert calls[1][0] == pytest.approx((59.95,)) and calls[2][0] == calls[1][0]
    passes = got.solver_stats["tightenings"]
    assert [len(p["dips"]) for p in passes] == [1, 1]
    assert got.solver_stats["iterations"] == 15
