"""Gaits from other tools.

- The default gait written as nodes (every 10th of 201 samples, and a non-uniform
  subset) imports back to the same gait: orbit residual <= 1e-10, the eigenvalues of
  both controllers equal to the original's to 1e-6, through the Python API and
  ``biped gait --import`` (CSV) then ``biped eig`` and ``biped simulate``.
- The default gait's own virtual constraints written as published (Bezier
  coefficients over s = (theta - theta+) / (theta- - theta+)) import to the same
  virtual-constraint eigenvalue.
- A Hermite-Simpson collocation of 12 intervals in absolute link angles (another tool,
  another convention: tests/foreign_gait.py) imports, closes to an exact orbit and gives
  the virtual-constraint eigenvalue delta_zero^2 of its own data (the angular momentum
  about the stance foot after / before the impact) within the import's own error; the
  same data against RABBIT without its rotor inertia are refused.
- Bad files and arguments: one line, exit 2, nothing written.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from foreign_gait import hermite_simpson_gait

from analysis import poincare_eigenvalues, vc_eigenvalue
from analysis.cli import main
from biped_casadi import BipedModel
from gait_opt import (MAX_IMPORT_TOL, Gait, GaitImportError, Nodes, fit_bezier_constraints,
                      import_gait)

M1 = np.array([0.2, -0.3, 0.1, 0.0])


def samples(gait, n=201):
    t = np.linspace(0.0, gait.T, n)
    q, dq, ddq = gait.evaluate(t)
    return Nodes(t, q, dq, ddq)


def write_csv(path, nodes: Nodes, acc=False):
    n = nodes.nq
    head = ["t"] + [f"q{i}" for i in range(1, n + 1)] + [f"dq{i}" for i in range(1, n + 1)]
    cols = [nodes.t[None], nodes.q, nodes.dq]
    if acc:
        head += [f"ddq{i}" for i in range(1, n + 1)]
        cols.append(nodes.ddq)
    rows = np.vstack(cols).T
    path.write_text(",".join(head) + "\n" + "\n".join(",".join(repr(float(v)) for v in r)
                                                      for r in rows) + "\n")
    return path


def same_eigenvalues(model, a, b):
    ea = poincare_eigenvalues(a, M1)
    eb = poincare_eigenvalues(b, M1)
    assert eb.status == ea.status and eb.fixed_point_residual < 1e-8
    va, vb = vc_eigenvalue(a), vc_eigenvalue(b)
    assert vb.status == va.status == "stable"
    return float(np.max(np.abs(ea.eigenvalues - eb.eigenvalues))), abs(va.eigenvalue - vb.eigenvalue)


@pytest.mark.parametrize("pick", ["every_10th", "non_uniform"])
def test_nodes_of_the_default_gait_import_back(model, gait, pick):
    nodes = samples(gait)
    if pick == "every_10th":
        nodes = nodes.every(10)
    else:
        idx = np.unique(np.r_[0, np.sort(np.random.default_rng(3).choice(
            np.arange(1, 200), 30, replace=False)), 200])
        nodes = Nodes(nodes.t[idx], nodes.q[:, idx], nodes.dq[:, idx])
    r = import_gait(model, nodes)
    assert r.success and r.bezier_degree == gait.options.bezier_degree
    assert r.orbit_residual_after <= 1e-10 and r.fit_error_q < 1e-12
    assert np.max(np.abs(r.gait.alpha - gait.alpha)) < 1e-9 and abs(r.gait.T - gait.T) < 1e-12
    d_tv, d_vc = same_eigenvalues(model, gait, r.gait)
    assert d_tv <= 1e-6 and d_vc <= 1e-6


@pytest.mark.parametrize("form", ["csv", "json"])
def test_as_many_nodes_as_coordinates(model, gait, tmp_path, form):
    """Five nodes of a five-coordinate robot: the (N, n) table is not read as (n, N) (the
    CSV's rows were taken for its coordinates)."""
    nodes = samples(gait, n=5)
    if form == "csv":
        src = write_csv(tmp_path / "five.csv", nodes)
    else:
        src = tmp_path / "five.json"
        src.write_text(json.dumps(dict(t=nodes.t.tolist(), q=nodes.q.T.tolist(),
                                       dq=nodes.dq.T.tolist())))
    r = import_gait(model, src)
    assert r.orbit_residual_after <= 1e-10 and abs(r.gait.T - gait.T) < 1e-12
    assert np.max(np.abs(r.gait.alpha - gait.alpha)) < 1e-8


def test_cli_import_then_eig_and_simulate(gait, tmp_path, capsys):
    src = write_csv(tmp_path / "steps.csv", samples(gait).every(10), acc=True)
    out = tmp_path / "imported.json"
    assert main(["gait", "--import", str(src), "--robot", "rabbit", "--out", str(out),
                 "--json"]) == 0
    body = json.loads(capsys.readouterr().out)
    assert body["orbit_residual_after"] <= 1e-10 and body["kind"] == "nodes"
    g = Gait.load(out)
    assert main(["eig", "--gait", str(out), "--controller", "vc", "--json"]) == 0
    vc = json.loads(capsys.readouterr().out)
    assert abs(vc["max_abs"] - vc_eigenvalue(gait).max_abs) <= 1e-6
    assert main(["eig", "--gait", str(out), "--m1", *map(str, M1), "--json"]) == 0
    tv = json.loads(capsys.readouterr().out)
    assert abs(tv["max_abs"] - poincare_eigenvalues(gait, M1).max_abs) <= 1e-6
    assert main(["simulate", "--gait", str(out), "--controller", "vc", "--steps", "4",
                 "--json"]) == 0
    sim = json.loads(capsys.readouterr().out)
    assert sim["status"] == "ok" and len(sim["steps"]) == 4
    assert g.T == pytest.approx(gait.T, abs=1e-12)


def test_published_virtual_constraints_import(model, gait, tmp_path):
    vc = fit_bezier_constraints(gait, degree=10)
    path = tmp_path / "vc.json"
    path.write_text(json.dumps({"virtual_constraints": vc.to_dict()}))
    r = import_gait(model, str(path))
    assert r.success and r.kind == "virtual_constraints"
    lam = vc_eigenvalue(gait).eigenvalue
    # delta_zero^2 of the constraints' own orbit: the impact of the gait, exactly
    assert abs(r.info["delta_zero_squared"] - lam) <= 1e-9
    assert r.info["invariance_residual"] < 1e-9
    got = vc_eigenvalue(r.gait)
    assert got.status == "stable" and abs(got.eigenvalue - lam) <= 1e-6
    assert r.orbit_residual_after <= 1e-10


@pytest.fixture(scope="module")
def foreign(model, gait):
    t, phi, dphi = hermite_simpson_gait(model, gait, n_intervals=12, speed=0.6)
    return Nodes(t, phi, dphi, source="Hermite-Simpson, 12 intervals, absolute angles")


def delta_zero_squared(model, nodes_phi: Nodes) -> float:
    S = np.eye(model.nq) - np.eye(model.nq, k=-1)
    q, dq = S @ nodes_phi.q, S @ nodes_phi.dq
    before = float(np.array(model.D(q[:, -1]))[0] @ dq[:, -1])   # about the stance foot
    after = float(np.array(model.D(q[:, 0]))[0] @ dq[:, 0])      # about the new one
    return (after / before) ** 2


def test_gait_from_another_tool(model, foreign):
    r = import_gait(model, foreign, angles="absolute")
    assert r.success and r.orbit_residual_after <= 1e-10
    assert r.speed == pytest.approx(0.6, abs=1e-9)
    lam = vc_eigenvalue(r.gait)
    own_error = max(r.fit_error_q, r.parameter_change, r.orbit_residual_before)
    assert own_error < 1e-4
    assert abs(lam.eigenvalue - delta_zero_squared(model, foreign)) <= own_error
    assert lam.eigenvalue == pytest.approx(lam.delta_zero_squared, abs=1e-9)


def test_another_robot_is_refused(model, foreign):
    d = model.description
    no_rotor = BipedModel(dataclasses.replace(d, rotor_inertia=0.0, name="RABBIT without rotors"))
    with pytest.raises(GaitImportError, match=r"not an orbit of RABBIT without rotors: .* "
                                              r"misses the periodic orbit by [0-9.]+ .*"
                                              r"impact map .*rotor inertia"):
        import_gait(no_rotor, foreign, angles="absolute")
    with pytest.raises(GaitImportError, match=r"--angles absolute"):
        import_gait(model, foreign)                # absolute angles read as relative


def test_tolerance_is_the_users(model, foreign):
    with pytest.raises(GaitImportError, match="tolerance 1e-08"):
        import_gait(model, foreign, angles="absolute", tol=1e-8)


def test_the_largest_tolerance_still_refuses_another_robot(model, foreign):
    """A tolerance is bounded (--import-tol 1e300 was taken, and the polish made the data
    of another robot an orbit of this one); the largest still refuses another robot."""
    no_rotor = BipedModel(dataclasses.replace(model.description, rotor_inertia=0.0))
    with pytest.raises(GaitImportError, match=f"tolerance {MAX_IMPORT_TOL:g}\\)"):
        import_gait(no_rotor, foreign, angles="absolute", tol=MAX_IMPORT_TOL)
    with pytest.raises(GaitImportError, match=f"tol must be at most {MAX_IMPORT_TOL:g} "):
        import_gait(model, foreign, angles="absolute", tol=MAX_IMPORT_TOL * 1.5)


BAD = {
    "missing.csv": (None, "not found"),
    "header.csv": ("t,a,b\n0,1,2\n", "the header must be t,q1..qn,dq1..dqn"),
    "nan.csv": ("HEAD\n" + "\n".join(f"{i},0,0,0,0,{'nan' if i == 3 else 0},0,0,0,0,0"
                                     for i in range(8)), "NaN"),
    "times.csv": ("HEAD\n" + "\n".join(f"{t},0,0,0,0,0,0,0,0,0,0" for t in (0, 1, 2, 2, 3, 4)),
                  "t must increase strictly"),
    "few.csv": ("HEAD\n0,0,0,0,0,0,0,0,0,0,0\n1,0,0,0,0,0,0,0,0,0,0\n", "a step needs at least 5"),
    "three.csv": ("t,q1,q2,q3,dq1,dq2,dq3\n" + "\n".join(f"{i},0,0,0,0,0,0" for i in range(6)),
                  # the robot named and what to do ("the robot 5" before)
                  "3 coordinates per node, the robot RABBIT has 5: a step of another robot? "
                  "(give its robot: import_gait's model, on the command line --robot)"),
    "shape.json": (json.dumps({"t": [0, 1, 2, 3, 4], "q": [[0] * 4] * 3, "dq": [[0] * 5] * 5}),
                   "q must be an (N, n) array"),
    "vc.json": (json.dumps({"virtual_constraints": {"bezier": [[0, 0, 0, 0]] * 4,
                                                    "theta_plus": 0.1, "phase": [1, 0, 0, 0, 0]}}),
                "missing key(s) theta_minus"),
    "steps.txt": ("x", "must end in .csv, .npz or .json"),
    "broken.npz": ("not a zip", "cannot read the NPZ file"),
    "urdf_header.csv": ("t,pitch,hip_left,knee_left,dpitch,dhip_left,dknee_left\n"
                        + "\n".join(f"{i},0,0,0,0,0,0" for i in range(6)),
                        "a step in URDF angles? (--angles urdf --stance HIP_JOINT)"),
    "text.csv": ("HEAD\n" + "\n".join(f"{i},0,0,0,0,0,0,{'n/a' if i == 2 else 0},0,0,0"
                                     for i in range(6)),
                 "line 4 has a value that is not a number: 'n/a' in column dq2"),
    "blank_lines.csv": ("HEAD\n\n" + "\n\n".join(f"{i},0,0,0,0,0,0,0,0,0{',0' if i != 3 else ''}"
                                                 for i in range(6)),
                        "line 9 has 10 values, the header 11"),
    "no_header.csv": ("\n".join(f"{i},0,0,0,0,0,0,0,0,0,0" for i in range(6)),
                      "no header line: line 1 holds numbers, not the column names "
                      "(t,q1..qn,dq1..dqn[,ddq1..ddqn])"),
    "semicolons.csv": ("HEAD\n" + "\n".join(f"{i};0;0;0;0;0;0;0;0;0;0" for i in range(6)),
                       "values must be separated by commas (this file uses ';')"),
    "tabs.csv": ("HEAD\n" + "\n".join(f"{i}\t0\t0\t0\t0\t0\t0\t0\t0\t0\t0" for i in range(6)),
                 "values must be separated by commas (this file uses tabs)"),
}
HEAD = "t," + ",".join(f"q{i}" for i in range(1, 6)) + "," + ",".join(f"dq{i}" for i in range(1, 6))


@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_import_files(tmp_path, capsys, name):
    text, message = BAD[name]
    src = tmp_path / name
    if text is not None:
        sep = ";" if "semicolons" in name else "\t" if "tabs" in name else ","
        src.write_text(text.replace("HEAD", HEAD.replace(",", sep)))
    out = tmp_path / "gait.json"
    assert main(["gait", "--import", str(src), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_bad_import_arguments(gait, tmp_path, capsys):
    src = write_csv(tmp_path / "s.csv", samples(gait).every(20))
    out = tmp_path / "g.json"
    for extra, message in [(["--import-tol", "-1"], "--import-tol must be a positive"),
                           (["--import-tol", "1e300"], "--import-tol must be at most 1 "),
                           (["--bezier-degree", "2"], "--bezier-degree must be from 4 to 20"),
                           (["--out", str(tmp_path / "g.txt")], "must end in .json"),
                           (["--speed", "0.3"], "--speed: an imported gait walks at its "
                                                "data's speed")]:
        assert main(["gait", "--import", str(src), "--out", str(out), *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1
        assert not out.exists()


def test_the_how_to_example_runs(capsys, monkeypatch):
    """The example of docs/howto/bring-your-robot.md (the walker's step in its own joint
    angles), as written, from the repository's root."""
    root = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(root)
    text = (root / "docs" / "howto" / "bring-your-robot.md").read_text()
    block = text.split("<!-- the block below runs in tests/test_gait_import.py -->")[1]
    code = block.split("```python\n", 1)[1].split("```", 1)[0]
    exec(compile(code, "bring-your-robot.md", "exec"), {})
    assert "orbit residual" in capsys.readouterr().out


def test_import_checks_the_model_and_hand_made_nodes(model, gait):
    """A robot's name for the model, and a Nodes with NaN (made by hand, not read from a
    file), were failures inside (AttributeError, StopIteration)."""
    from gait_opt import GaitImportError, Nodes, import_gait, read_nodes
    t = np.linspace(0.0, gait.T, 41)
    with pytest.raises(TypeError, match="^model: a robot model is needed"):
        import_gait("rabbit", {"t": t, "q": gait.q(t).T, "dq": gait.dq(t).T})
    bad = Nodes(t, np.full((5, t.size), np.nan), gait.dq(t))
    with pytest.raises(GaitImportError, match="^gait: q has a NaN or infinite value$"):
        import_gait(model, bad)
    ok = import_gait(model, Nodes(t, gait.q(t), gait.dq(t), gait.ddq(t), source="by hand"))
    assert ok.status == "imported" and ok.gait.orbit_residual()["q"] < 1e-9
    with pytest.raises(TypeError, match="^path must be a file name"):
        read_nodes(None)
