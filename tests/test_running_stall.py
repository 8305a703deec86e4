"""The running step's stall watch (gait_opt.running_solve): a search whose constraint
violation no longer falls is ended, and a failed solve says which constraints its last
iterate violates and which torques sit at their limit.  Small grids only (a few seconds);
the figures on the default grid (converging speeds unchanged, an unreachable speed
failing in about 30 s instead of minutes) are in the running how-to."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from gait_opt.running import RunningOptions, optimize_running
from gait_opt.running_solve import FEASIBLE, STALL_FACTOR, STALL_WINDOW, _NAMES, stalled


@pytest.mark.parametrize("history, window, expected", [
    ([5.0] * 10, 5, True),                        # no progress at all
    ([5.0] * 5, 5, False),                        # not more than a window yet
    ([5.0] * 10, None, False),                    # no watch
    ([8.0] * 5 + [4.1] + [9.0] * 4, 5, True),     # 4.1 > 0.5 * 8: not quite halved
    ([8.0] * 5 + [3.9] * 5, 5, False),            # halved within the window
    ([1e-3] * 5 + [2e-7] * 5, 5, False),          # feasible: never stalled
    ([1e-3] * 5 + [FEASIBLE * 2] + [1.0] * 4, 5, False),  # progress, though it rose again
    ([1.0, FEASIBLE / 2] + [1e-3] * 5, 5, False),  # feasible once: left for the cost
    ([1.0, FEASIBLE * 2] + [1e-3] * 5, 5, True),   # never feasible, then no progress
])
def test_stalled_on_made_up_histories(history, window, expected):
    assert stalled(history, window) is expected


def test_stalled_reads_the_window_only():
    """The smallest of the window is compared with the smallest before it."""
    h = [10.0, 1.0] + [0.6] * 3
    assert stalled(h, 3) and not stalled(h, 3, factor=0.7)
    assert STALL_FACTOR < 1 and STALL_WINDOW >= 1


def test_an_unreachable_speed_stops_on_a_stall(model):
    """6 m/s on a small grid: the watch ends the search before IPOPT's limit, and the
    last iterate is described in named groups."""
    from analysis.cli.running import failure
    o = RunningOptions(speed=6.0, n_stance=6, n_flight=4, stall_window=10,
                       ipopt={"max_iter": 300})
    s = optimize_running(model, o).solver_stats
    assert not s["success"] and s["return_status"] == "Stalled", s
    assert 10 <= s["iterations"] < 300 and s["stall_window"] == 10
    labels = {name for _, _, name, _ in _NAMES}
    assert s["violated"] and all(d["name"] in labels and d["violation"] > FEASIBLE
                                 for d in s["violated"])
    joints = {d["joint"] for d in s["torque_at_limit"]}
    assert joints <= {"stance knee", "stance hip (torso)", "swing hip", "swing knee"}
    line = failure(6.0, s)
    assert "\n" not in line and "did not halve over 10 iterations" in line
    assert s["violated"][0]["name"] in line


def test_a_guess_is_described_in_named_groups(model, monkeypatch):
    """No iteration: the built-in guess violates the dynamics and more (here a stance
    of at least 0.5 s, the guess's being shorter); every violated row is traced to its
    constraint (none falls back to its source line), the phases told apart."""
    import gait_opt.running_solve as rs
    every = []

    def all_groups(opti, g, rows, **kw):
        every.extend(original(opti, g, rows, most=None))
        return every[:3]
    original = rs.violated
    monkeypatch.setattr(rs, "violated", all_groups)
    o = RunningOptions(n_stance=4, n_flight=3, stall_window=None, ipopt={"max_iter": 0},
                       stance_time_bounds=(0.5, 0.8))
    s = optimize_running(model, o).solver_stats
    labels = {name for _, _, name, _ in _NAMES}
    assert s["return_status"] == "Maximum_Iterations_Exceeded" and len(every) > 3
    names = {d["name"] for d in every}
    assert {"collocation defects of stance (the dynamics)", "stance duration bounds"} <= names
    assert "flight duration bounds" not in names
    assert all(d["name"] in labels for d in every), every


@pytest.mark.parametrize("args, window", [([], STALL_WINDOW), (["--max-iter", "50"], None)])
def test_command_line_max_iter_is_the_long_search(tmp_path, monkeypatch, capsys, args, window):
    """--max-iter turns the watch off; a failure is one line saying what the last
    iterate showed, nothing written."""
    from analysis.cli import main, running as cli
    seen = []
    stats = {"success": False, "return_status": "Stalled", "iterations": 180,
             "stall_window": STALL_WINDOW,
             "violated": [{"name": "Fz = 0 at takeoff", "unit": "N", "violation": 0.0124,
                           "count": 1}],
             "torque_at_limit": [{"joint": "stance knee", "count": 33, "limit": 150.0}]}

    def solve(model, opts, **kw):
        seen.append(opts)
        return SimpleNamespace(success=False, solver_stats=stats)
    monkeypatch.setattr(cli, "optimize_running", solve)
    monkeypatch.chdir(tmp_path)
    assert main(["running", "--speed", "4", *args]) == 2
    assert [o.stall_window for o in seen] == [window]
    assert seen[0].ipopt == ({"max_iter": 50} if args else {})
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "did not converge at 4 m/s" in err
    assert "stance knee at 33 points" in err and "Fz = 0 at takeoff violated by 0.012 N" in err
    assert list(tmp_path.iterdir()) == []
