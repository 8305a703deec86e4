"""`biped eig` and `biped m1` on the command line: the JSON is the library's result,
user errors are one line and exit code 2."""
from __future__ import annotations

import json

import numpy as np
import pytest

from analysis import poincare_eigenvalues, vc_eigenvalue
from analysis.cli import main as biped_main


@pytest.fixture(scope="module")
def gait_file(gait, tmp_path_factory):
    return str(gait.save(tmp_path_factory.mktemp("cli") / "gait.json"))


def run_json(capsys, *args):
    rc = biped_main(list(args))
    out = capsys.readouterr()
    assert rc == 0, out.err
    return json.loads(out.out)


def test_eig_json_is_the_library_result(model, gait, gait_file, capsys):
    M1 = [-2.5, 5.0, -2.5, 5.0]
    body = run_json(capsys, "eig", "--gait", gait_file, "--m1", *map(str, M1), "--json")
    ref = poincare_eigenvalues(gait, M1)
    assert np.array(body["A"]).shape == (2, 2)
    np.testing.assert_allclose(body["A"], ref.A, rtol=1e-12)
    assert body["max_abs"] == pytest.approx(ref.max_abs, rel=1e-12)
    assert body["status"] == ref.status == "stable" and body["success"] is True
    assert [complex(*e) for e in body["eigenvalues"]] == pytest.approx(list(ref.eigenvalues))
    assert body["method"] == "variational"


def test_eig_ad_method_reports_the_fixed_point(gait_file, capsys):
    body = run_json(capsys, "eig", "--gait", gait_file, "--m1", "0", "0", "0", "0",
                    "--method", "ad", "--json")
    assert body["fixed_point_residual"] < 1e-8 and body["status"] == "unstable"
    assert body["max_abs"] == pytest.approx(12.13, abs=0.01)


def test_eig_rejoin_is_the_library_result(gait, gait_file, capsys):
    """--rejoin reaches A^z (a robust design's simulate_args carry it), tv only."""
    M1 = [-2.5, 5.0, -2.5, 5.0]
    body = run_json(capsys, "eig", "--gait", gait_file, "--m1", *map(str, M1),
                    "--rejoin", "0.75", "--json")
    ref = poincare_eigenvalues(gait, M1, rejoin=0.75)
    np.testing.assert_allclose(body["A"], ref.A, rtol=1e-12)
    assert abs(ref.max_abs - poincare_eigenvalues(gait, M1).max_abs) > 1e-3
    assert biped_main(["eig", "--gait", gait_file, "--controller", "vc", "--rejoin",
                       "0.75"]) == 2
    assert "--rejoin applies to the time-varying" in capsys.readouterr().err


def test_eig_singular_and_vc(model, gait, gait_file, capsys):
    body = run_json(capsys, "eig", "--gait", gait_file, "--m1", "1.70", "0", "0", "0", "--json")
    assert body["status"] == "singular" and body["success"] is False and body["max_abs"] is None
    body = run_json(capsys, "eig", "--gait", gait_file, "--controller", "vc", "--json")
    assert body["eigenvalue"] == pytest.approx(vc_eigenvalue(gait).eigenvalue, rel=1e-12)
    assert body["status"] == "stable"


def test_eig_names_a_gait_whose_torso_passes_the_fall_bound(model, gait_file, tmp_path,
                                                            capsys):
    """RABBIT's optimum at 1.2 m/s leans its torso past the simulator's fall bound: its
    map may be stable, but every walk of it is a fall, and `biped eig` says so under
    both controllers; the default gait gets no such line."""
    from analysis.gait_metrics import torso_fall
    from gait_opt import GaitOptions, optimize_gait
    fast = optimize_gait(model, GaitOptions(speed=1.2))
    lean, past, bound = torso_fall(fast)
    assert past
    f = str(fast.save(tmp_path / "fast.json"))
    M1 = ["-2.5", "5.0", "-2.5", "5.0"]
    for args in (["--controller", "vc"], ["--m1", *M1]):
        assert biped_main(["eig", "--gait", f, *args]) == 0
        out = capsys.readouterr().out
        assert f"torso leans {lean:.4g} rad, PAST the simulator's fall bound" in out, out
        assert biped_main(["eig", "--gait", gait_file, *args]) == 0
        assert "fall bound" not in capsys.readouterr().out


def test_m1_json_group2(gait_file, capsys):
    body = run_json(capsys, "m1", "--gait", gait_file, "--group", "2", "--json")
    assert body["group"] == 2 and body["status"] == "stable" and body["success"]
    assert body["max_abs"] < 1e-3 and abs(body["a"]) < 1e-9 and abs(body["b"]) < 1e-9
    assert body["grid_best"]["max_abs"] > body["max_abs"]


@pytest.mark.parametrize("args, message", [
    (["eig", "--gait", "{gait}", "--m1", "1", "2", "3"], "--m1 takes 4"),
    (["eig", "--gait", "{gait}", "--m1", "nan", "0", "0", "0"], "finite"),
    (["eig", "--gait", "{gait}"], "--m1"),
    (["eig", "--gait", "{gait}", "--controller", "vc", "--m1", "0", "0", "0", "0"], "--m1"),
    (["eig", "--gait", "{missing}", "--m1", "0", "0", "0", "0"], "not found"),
    (["m1", "--gait", "{missing}"], "not found"),
])
def test_user_errors_are_one_line_exit_2(gait_file, tmp_path, capsys, args, message):
    subs = dict(gait=gait_file, missing=str(tmp_path / "none.json"))
    rc = biped_main([a.format(**subs) for a in args])
    cap = capsys.readouterr()
    lines = cap.err.strip().splitlines()
    assert rc == 2 and cap.out == ""
    assert len(lines) == 1 and message in lines[0] and lines[0].startswith(f"biped {args[0]}:")


# ------------------------------------------------------- issue 12: a newcomer's path
class _Terminal:
    """stderr as a terminal (progress lines are shown only there)."""

    def __init__(self):
        self.text = ""

    def write(self, s):
        self.text += s

    def flush(self):
        pass

    def isatty(self):
        return True


def test_default_gait_optimisation_is_announced(gait, capsys, monkeypatch):
    """Issue 12: without --gait the first command optimised the default gait for ~20 s
    with no word on screen."""
    import analysis.cli.common as common
    called = []

    def optimize_gait(model=None, progress=None, cache=True):   # as if nothing were cached yet
        called.append(progress)
        progress("optimising the reference gait of RABBIT (once) ...")
        return gait

    monkeypatch.setattr(common, "optimize_gait", optimize_gait)
    term = _Terminal()
    monkeypatch.setattr("sys.stderr", term)
    assert biped_main(["eig", "--m1", "0", "0", "0", "0"]) == 0
    assert "biped eig: optimising the reference gait" in term.text
    term.text = ""
    assert biped_main(["eig", "--m1", "0", "0", "0", "0", "--json"]) == 0
    assert term.text == ""                      # --json: silent
    assert len(called) == 2


def test_long_waits_show_progress_on_a_terminal_only(gait_file, tmp_path, monkeypatch, capsys):
    term = _Terminal()
    monkeypatch.setattr("sys.stderr", term)
    args = ["simulate", "--gait", gait_file, "--steps", "1", "--animate",
            str(tmp_path / "w.gif")]
    assert biped_main(args) == 0
    assert "simulating 1 step(s)" in term.text and "writing the animation" in term.text
    monkeypatch.setattr("sys.stderr", _NotATerminal := type(
        "NotATerminal", (_Terminal,), {"isatty": lambda self: False})())
    assert biped_main(args) == 0
    assert _NotATerminal.text == ""


@pytest.mark.parametrize("args", [
    ["eig", "--m1", "1e6", "0", "0", "0"],                # the largest valid M1
    ["eig", "--m1", "1.6894", "0", "0", "0"],             # next to the singular value
    ["eig", "--m1", "1e6", "-1e6", "1e6", "-1e6", "--method", "ad"],
    ["sweep", "--grid", "2", "--range", "-1e6", "1e6"],
    ["simulate", "--steps", "1", "--perturb", "0.5", "5"],   # falls at once
])
def test_no_numerical_warning_reaches_the_terminal(gait_file, capsys, args):
    """Issue 12: `eig --m1 1e300 0 0 0` answered no_impact with numpy warnings on stderr
    and an impact time printed.  Now 1e300 is refused (tests/test_cli_bad_inputs.py) and
    the extremes that are valid print no warning."""
    rc = biped_main([args[0], "--gait", gait_file, *args[1:]])
    cap = capsys.readouterr()
    assert rc == (1 if args[0] == "simulate" else 0) and cap.err == "", cap.err  # (it falls)
    if args[0] == "eig" and "status: singular" in cap.out:
        assert "impact at" not in cap.out and "A^z" not in cap.out


def test_negative_numbers_in_any_notation_are_values(gait_file, capsys):
    body = run_json(capsys, "eig", "--gait", gait_file, "--m1", "-1e-3", "-2.5E0", "-.5",
                    "-0", "--json")
    assert body["M1"] == [-1e-3, -2.5, -0.5, 0.0]


def test_grid_spans_the_range():
    """Issue 12: `sweep --grid 1` evaluated only the low corner of the range."""
    from analysis.sweeps import grid_points
    with pytest.raises(ValueError, match="n .* must be an integer >= 2"):
        grid_points(1, -10, 10)
    P = grid_points(2, -10, 10)
    assert P.min() == -10 and P.max() == 10 and len(P) == 16


def test_m1_outside_the_valid_range_is_a_value_error(model, gait):
    from biped_casadi.control.output_law import M1_LIMIT
    with pytest.raises(ValueError, match=r"M1: components must lie within"):
        poincare_eigenvalues(gait, [1e300, 0, 0, 0])
    r = poincare_eigenvalues(gait, [M1_LIMIT, 0, 0, 0])
    ad = poincare_eigenvalues(gait, [M1_LIMIT, 0, 0, 0], method="ad")
    assert r.status == ad.status == "unstable"
    assert r.max_abs == pytest.approx(ad.max_abs, rel=1e-4)     # still meaningful there


def test_ctrl_c_that_a_library_turns_into_another_error_is_an_interruption(
        gait_file, capsys, monkeypatch):
    """Ctrl-C inside CasADi's DM.__array__ in a task came out of ``biped terrain`` as
    "error: --scheduler: evaluate_chunk: SystemError: ... returned a result with an
    exception set" (exit 2, as for bad input); any error after a Ctrl-C is the
    interruption (130), here in a sweep whose chunk turns it into a ValueError."""
    import os
    import signal

    from analysis.cli import sweep as cli_sweep

    def interrupted_inside_a_library(*a, **k):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            raise AssertionError("no interruption")
        except KeyboardInterrupt:
            raise ValueError("scheduler: evaluate_chunk: SystemError: <function "
                             "DM.__array__> returned a result with an exception set") from None

    monkeypatch.setattr(cli_sweep, "run_sweep", interrupted_inside_a_library)
    # Ctrl-C as in a terminal: a suite started as a background job inherits SIGINT ignored
    # (the command line then leaves it ignored, and the kill above would do nothing)
    outer = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        rc = biped_main(["sweep", "--gait", str(gait_file), "--grid", "2"])
        err = capsys.readouterr().err
        assert rc == 130 and err.strip().splitlines()[-1] == "biped sweep: interrupted", err
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler   # put back
    finally:
        signal.signal(signal.SIGINT, outer)


def test_m1_robust_help_states_the_target_the_gait_path_uses(capsys):
    """`biped m1 --help` names the convergence step of the settings `--robust --gait`
    runs with (FIT), not another number."""
    import re

    from analysis.design.codesign import FIT

    assert biped_main(["m1", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())       # argparse wraps the lines
    steps = re.findall(r"perturbation below 1e-3 by step (\d+)", text)
    assert steps == [str(FIT.converge_by)]
