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
    ref = poincare_eigenvalues(model, gait, M1)
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


def test_eig_singular_and_vc(model, gait, gait_file, capsys):
    body = run_json(capsys, "eig", "--gait", gait_file, "--m1", "1.70", "0", "0", "0", "--json")
    assert body["status"] == "singular" and body["success"] is False and body["max_abs"] is None
    body = run_json(capsys, "eig", "--gait", gait_file, "--controller", "vc", "--json")
    assert body["eigenvalue"] == pytest.approx(vc_eigenvalue(model, gait).eigenvalue, rel=1e-12)
    assert body["status"] == "stable"


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
