"""The running controller exported as C (biped_casadi.control.export_running): the compiled
library against the Python law at random states of both phases (both laws, saturation),
its return codes, the files (C99 without warnings, no allocation, the README's build
line, the example), 30 MuJoCo strides with the library against the Python law, and
``biped export-running`` / ``biped mujoco-running --compiled`` with their bad inputs."""
from __future__ import annotations

import dataclasses
import hashlib
import json
import re
import subprocess

import numpy as np
import pytest

from analysis.cli import export_running as export_running_cli
from analysis.cli import main as biped_main
from analysis.verify_export import TORQUE_RTOL, time_example
from analysis.verify_running_export import (STRIDE_TOL, compare_running_mujoco,
                                            compare_running_states)
from biped_casadi.control.compiled import CompilerError, find_c_compiler
from biped_casadi.control.compiled_running import CompiledRunningLaw, check_running_export
from biped_casadi.control.export import c_sources, exported_law
from biped_casadi.control.export_folder import check_destination, write_export
from biped_casadi.control.export_running import (RUNNING_GENERATED, RUNNING_HEADER,
                                                 RUNNING_INFO, RUNNING_WRAPPER,
                                                 exported_running_law, running_c_sources)
from biped_casadi.control.running import RunningController
from biped_casadi import VirtualConstraintController

pytest.importorskip("mujoco")
CC = find_c_compiler()
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler (gcc, cc or $CC) on this machine")
STABLE_M1 = (0.0, 0.95, 0.95, 0.0)


def export_and_build(ctrl, folder):
    write_export(running_c_sources(exported_running_law(ctrl), {"gait file": "test"}), folder)
    return CompiledRunningLaw.build(folder, ctrl, folder.parent / f"{folder.name}.so")


@pytest.fixture(scope="module")
def pd(model, running_gait, tmp_path_factory):
    """The how-to's design: PD Kp 400, Kd 30, M1 = (0, 0.95, 0.95, 0)."""
    ctrl = RunningController(model, running_gait, 400.0, 30.0, M1=STABLE_M1)
    if CC is None:
        return ctrl, None
    return ctrl, export_and_build(ctrl, tmp_path_factory.mktemp("pd") / "export")


@needs_cc
def test_compiled_torques_equal_the_python_law(pd):
    ctrl, lib = pd
    r = compare_running_states(lib, ctrl, n=2000, seed=1)
    assert r.success, r.message
    assert max(r.max_torque_rel.values()) <= TORQUE_RTOL
    assert r.return_codes == {"0": 4000}
    # CasADi's C of the controller's own Functions: the same arithmetic as its VM
    assert r.bitwise_equal == {"stance": 2000, "flight": 2000}, r.message


@needs_cc
def test_computed_torque_with_saturation(model, running_gait, tmp_path):
    """The other law, its torques clipped at a limit the random states exceed."""
    ctrl = RunningController(model, running_gait, 100.0, 20.0, M1=STABLE_M1,
                             law="computed_torque", saturate=True, torque_limit=60.0)
    lib = export_and_build(ctrl, tmp_path / "ct")
    r = compare_running_states(lib, ctrl, n=500, seed=2)
    assert r.success and max(r.max_torque_rel.values()) <= TORQUE_RTOL, r.message
    X = running_gait.x_stance
    rc, u = lib.torque(0, 0.1, X[:5, 3] + 0.3, X[5:, 3] + 3.0)
    assert rc == 0 and np.max(np.abs(u)) == 60.0
    header = (tmp_path / "ct" / RUNNING_HEADER).read_text()
    assert "computed torque" in header and "clipped at +-60.0 N m" in header


@needs_cc
def test_return_codes(pd, running_gait):
    ctrl, lib = pd
    X, Xf = running_gait.x_stance, running_gait.x_flight
    q, dq = X[:5, 2], X[5:, 2]
    assert lib.torque(0, 0.05, q, dq)[0] == 0
    assert lib.torque(1, 0.02, Xf[:7, 1], Xf[7:, 1])[0] == 0
    for t in (-1.0, 5.0):                    # the reference's polynomials continue
        assert lib.torque(0, t, q, dq)[0] == 0
    for phase in (2, -1):
        rc, u = lib.torque(phase, 0.05, q, dq)
        assert rc == 2 and np.all(np.isnan(u))
    for bad in ((0.05, np.r_[np.nan, q[1:]], dq), (0.05, q, np.r_[dq[:4], np.inf]),
                (np.nan, q, dq)):
        rc, u = lib.torque(0, *bad)
        assert rc == 3 and np.all(np.isnan(u))
    assert lib.torque(1, 0.02, Xf[:7, 1], np.r_[Xf[7:13, 1], np.nan])[0] == 3


@needs_cc
def test_files_are_plain_c99_and_the_readme_build_works(pd, tmp_path):
    ctrl, _ = pd
    folder = tmp_path / "export"
    write_export(running_c_sources(exported_running_law(ctrl), {"gait file": "x"}), folder)
    assert sorted(p.name for p in folder.glob("*.c")) == sorted([RUNNING_WRAPPER,
                                                                  RUNNING_GENERATED])
    header = (folder / RUNNING_HEADER).read_text()
    assert re.findall(r"^int (\w+)\(", header, re.M) == ["biped_running_sizes",
                                                         "biped_running_torque"]
    assert "Kp = [400.0, 400.0, 400.0, 400.0]" in header and "M1 = [0.0, 0.95" in header
    for f in (RUNNING_WRAPPER, RUNNING_GENERATED):
        src = (folder / f).read_text()
        assert not re.search(r"\b(malloc|calloc|realloc|free|printf|fopen)\s*\(", src)
        assert set(re.findall(r"#include\s*[<\"]([^>\"]+)", src)) <= {"math.h", "stddef.h",
                                                                     RUNNING_HEADER}
        extra = ["-Wextra"] if f == RUNNING_WRAPPER else []
        r = subprocess.run([*CC, "-std=c99", "-pedantic", "-Wall", *extra, "-Werror",
                            "-O2", "-c", str(folder / f), "-o", str(tmp_path / f"{f}.o")],
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stderr[:2000]
    lib = tmp_path / "libbiped_running.so"
    cmd = f"{' '.join(CC)} -O2 -shared -fPIC -o {lib} {folder}/*.c -lm"
    assert subprocess.run(cmd, shell=True).returncode == 0 and lib.is_file()
    assert CompiledRunningLaw(lib, 5, 4, 7).nqe == 7
    us, line = time_example(folder, CC, calls=20000, function="biped_running_torque")
    assert 0 < us < 100 and "0 non-zero returns" in line


@needs_cc
def test_mujoco_strides_equal_with_the_library(pd):
    """30 strides from a perturbed landing: every record the same as with the Python law
    (the library's torques are the Python law's bit for bit, and MuJoCo is deterministic)."""
    ctrl, lib = pd
    x0 = np.asarray(ctrl.gait.x_stance, float)[:, 0].copy()
    x0[5:] += 0.01
    r = compare_running_mujoco(lib, ctrl, x0, strides=30)
    assert r.success and r.strides == 30 and r.compiled_status == "ran", r.message
    assert r.max_difference <= STRIDE_TOL and r.identical_strides == 30


def test_exported_running_law_refuses(gait):
    with pytest.raises(ValueError, match="^controller: exported_running_law takes a "
                                         "RunningController"):
        exported_running_law(VirtualConstraintController(gait))
    with pytest.raises(TypeError, match=r"^law: an ExportedRunningLaw is needed"):
        running_c_sources(exported_law(VirtualConstraintController(gait)))


def test_a_running_export_replaces_a_walking_one(pd, gait, tmp_path):
    """Either kind of export is recognised as one (and replaced); the export checks
    against its controller."""
    ctrl, _ = pd
    out = tmp_path / "out"
    write_export(c_sources(exported_law(VirtualConstraintController(gait))), out)
    write_export(running_c_sources(exported_running_law(ctrl)), out)
    assert (out / RUNNING_HEADER).is_file() and check_destination(out) == out
    assert check_running_export(out, ctrl)["kind"] == "running"
    with pytest.raises(ValueError, match="the export's Kd is"):
        check_running_export(out, ctrl.with_gains(Kd=31.0))
    with pytest.raises(ValueError, match="the export's M1 is"):
        check_running_export(out, ctrl.with_gains(M1=np.zeros(4)))


# ----------------------------------------------------------------- command line
def run(capsys, *args):
    rc = biped_main([str(a) for a in args])
    return rc, capsys.readouterr()


@needs_cc
def test_cli_export_running_and_mujoco_compiled(running_gait, tmp_path, capsys):
    g = running_gait.save(tmp_path / "running.json")
    out = tmp_path / "export"
    rc, o = run(capsys, "export-running", "--gait", g, "--out", out, "--verify", "--states",
                200, "--strides", 3, "--json")
    d = json.loads(o.out)
    assert rc == 0 and d["status"] == "verified", o.err
    v = d["verification"]
    assert max(v["states"]["max_torque_rel"].values()) <= TORQUE_RTOL
    assert v["mujoco"]["strides"] == 3 and v["mujoco"]["identical_strides"] == 3
    assert v["c_us"] > 0
    assert d["gait_sha256"] == hashlib.sha256(g.read_bytes()).hexdigest()
    assert (out / "running.json").read_bytes() == g.read_bytes()
    assert "us per `biped_running_torque` call" in (out / "README.md").read_text()
    runs = []
    for extra in ([], ["--compiled", out]):
        rc, o = run(capsys, "mujoco-running", "--gait", g, "--strides", 3, "--json", *extra)
        assert rc == 0, o.err
        runs.append(json.loads(o.out))
    assert runs[1]["controller"]["compiled"]["export"] == str(out)
    assert runs[0]["strides"] == runs[1]["strides"]
    rc, o = run(capsys, "mujoco-running", "--gait", g, "--strides", 3, "--compiled", out)
    assert rc == 0 and f"the law compiled from the export {out}" in o.out


@needs_cc
def test_cli_verify_that_compared_no_stride_is_not_verified(running_gait, tmp_path, capsys):
    """--kp 1e300: both MuJoCo runs stop in their first stride (a double contact), so the
    comparison had no stride record; --verify said 'verified', wrote the export and
    exited 0.  Now 'unverified', exit 1, nothing written; --strides 0 (the states only)
    still verifies."""
    g = running_gait.save(tmp_path / "running.json")
    out = tmp_path / "export"
    args = ["export-running", "--gait", g, "--out", out, "--kp", "1e300", "--verify",
            "--states", 50]
    rc, o = run(capsys, *args, "--strides", 2, "--json")
    d = json.loads(o.out)
    m = d["verification"]["mujoco"]
    assert (rc, d["status"], m["status"], m["strides"]) == (1, "unverified",
                                                           "nothing_compared", 0), o.out
    assert m["python_status"] == m["compiled_status"] != "ran"
    rc, o = run(capsys, *args, "--strides", 2)
    assert rc == 1 and "both MuJoCo runs stopped in stride 1" in o.out, o.out
    assert "wrote" not in o.out and not out.exists()
    rc, o = run(capsys, *args, "--strides", 0, "--json")
    assert rc == 0 and json.loads(o.out)["status"] == "verified", o.err
    assert out.exists()


def test_stride_records_with_nan_compare_equal(running_gait):
    """A NaN in both records (the takeoff guard's gap of a stride whose guard did not
    cross) is no difference, in one record only an infinite one; equal infinities are
    equal.  Before, NaN - NaN made the difference NaN: 'different' for identical runs."""
    from analysis.verify_running_export import _stride_difference
    from biped_casadi.mujoco.running_records import RunningStride
    a = RunningStride(index=0, t_landing=0.0, stance=0.3, flight=0.1, step_length=0.5,
                      speed=1.3, landing_state=[0.1] * 10, deviation=1.0,
                      peak_torque=float("inf"), clipped_time=0.0, slip=0.0, fz_max=1e3,
                      bounce_time=0.0, takeoff_guard_gap=float("nan"))
    b = dataclasses.replace(a, speed=1.3 + 1e-12)
    assert _stride_difference(a, a) == 0.0
    assert _stride_difference(a, b) == pytest.approx(1e-12, rel=1e-3)
    assert _stride_difference(a, dataclasses.replace(a, takeoff_guard_gap=0.0)) == np.inf


@needs_cc
def test_cli_verify_with_a_stride_whose_guard_did_not_cross(running_gait, tmp_path, capsys):
    """--kd 1e300: the MuJoCo runs stop in stride 2, the first stride's takeoff guard gap
    NaN in both: --verify ended in 'internal error: TypeError' (the NaN difference, null
    in the result, formatted as a number).  Now the stride compares equal."""
    g = running_gait.save(tmp_path / "running.json")
    rc, o = run(capsys, "export-running", "--gait", g, "--out", tmp_path / "export", "--kd",
                "1e300", "--verify", "--states", 50, "--strides", 3)
    assert rc == 0 and "verification: verified" in o.out, o.err + o.out
    assert "records differ by at most 0 " in o.out


def _bad(capsys, *args):
    rc, o = run(capsys, *args)
    assert rc == 2 and o.out == "" and len(o.err.strip().splitlines()) == 1, o.err
    return o.err


def test_cli_bad_inputs(running_gait, pd, tmp_path, capsys, monkeypatch):
    ctrl, _ = pd
    g = running_gait.save(tmp_path / "running.json")
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "todo.txt").write_text("mine\n")
    E = ["export-running", "--gait", g]
    assert "other than an export" in _bad(capsys, *E, "--out", tmp_path / "notes")
    assert "--m1 takes 4 numbers" in _bad(capsys, *E, "--m1", 1, 2, "--out", tmp_path / "o")
    assert "--kp" in _bad(capsys, *E, "--kp", -1, "--out", tmp_path / "o")
    assert "--strides" in _bad(capsys, *E, "--strides", -1, "--out", tmp_path / "o")
    assert "--gait" in _bad(capsys, "export-running", "--gait", tmp_path / "none.json",
                            "--out", tmp_path / "o")
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    assert "no C compiler" in _bad(capsys, *E, "--out", tmp_path / "o", "--verify")
    monkeypatch.delenv("CC")
    assert not (tmp_path / "o").exists()
    out = tmp_path / "export"
    write_export(running_c_sources(exported_running_law(ctrl)), out)
    M = ["mujoco-running", "--gait", g, "--strides", 1]
    assert "the export's Kp is" in _bad(capsys, *M, "--compiled", out, "--kp", 300)
    assert "not a folder" in _bad(capsys, *M, "--compiled", tmp_path / "none")
    assert "not a running export" in _bad(capsys, *M, "--compiled", tmp_path / "notes")
    assert "empty folder name" in _bad(capsys, *M, "--compiled", "")
    (tmp_path / "notes" / "controller.json").write_text("[1, 2]\n")
    assert "not a running export" in _bad(capsys, *M, "--compiled", tmp_path / "notes")
    (tmp_path / "notes" / "controller.json").write_text('{"kind": "running"}\n')
    assert "another robot" in _bad(capsys, *M, "--compiled", tmp_path / "notes")


def test_cli_saturate_reaches_the_export_and_the_verification(model, running_gait, tmp_path,
                                                              capsys, monkeypatch):
    """--saturate: the written controller clips at the robot's limit, and --verify
    compares the C law with a Python law that clips the same (no compiler needed: the
    verification is intercepted); mujoco-running --compiled takes that export only with
    --saturate."""
    g = running_gait.save(tmp_path / "running.json")
    for extra in ([], ["--saturate"]):
        out = tmp_path / f"export{len(extra)}"
        rc, o = run(capsys, "export-running", "--gait", g, "--out", out, *extra)
        info = json.loads((out / RUNNING_INFO).read_text())["controller"]
        assert rc == 0 and info["saturate"] is bool(extra), o.err
        assert ("torques clipped at" in o.out) is bool(extra)
    assert info["torque_limit"] == float(np.asarray(model.description.torque_limit))
    seen = []

    def fake_verify(folder, ctrl, *args):
        seen.append((json.loads((folder / RUNNING_INFO).read_text())["controller"],
                     ctrl.saturate))
        raise CompilerError("stopped by the test")

    monkeypatch.setattr(export_running_cli, "check_target", lambda args: ["cc"])
    monkeypatch.setattr(export_running_cli, "verify_running_export", fake_verify)
    for extra in ([], ["--saturate"]):
        assert "stopped by the test" in _bad(capsys, "export-running", "--gait", g, "--out",
                                             tmp_path / "v", "--verify", *extra)
    assert [(c["saturate"], s) for c, s in seen] == [(False, False), (True, True)]
    assert not (tmp_path / "v").exists()
    M = ["mujoco-running", "--gait", g, "--strides", 1]
    assert "the export's saturate is True, this run's False" in _bad(
        capsys, *M, "--compiled", tmp_path / "export1")
    rc, o = run(capsys, *M, "--saturate", "--json")
    assert rc == 0 and json.loads(o.out)["controller"]["saturate"] is True, o.err


@needs_cc
def test_cli_saturate_at_a_torque_limit(model, running_gait, tmp_path, capsys):
    """``--saturate --torque-limit U``: the C code clips at U (compiled and called here),
    --verify compares it with the Python law clipped alike and runs MuJoCo with motors of
    U; ``mujoco-running --saturate --torque-limit U`` runs that export and the Python law
    to the same strides, every peak at most U; --torque-limit alone is refused."""
    U = 80.0                 # below the 1.5 m/s orbit's peak (106 N m): its torques clip
    g = running_gait.save(tmp_path / "running.json")
    out = tmp_path / "export"
    rc, o = run(capsys, "export-running", "--gait", g, "--out", out, "--saturate",
                "--torque-limit", U, "--verify", "--states", 200, "--strides", 2, "--json")
    d = json.loads(o.out)
    assert rc == 0 and d["status"] == "verified", o.err
    assert d["clipped_at"] == U and d["controller"]["torque_limit"] == U
    assert d["verification"]["mujoco"]["identical_strides"] == 2
    ctrl = RunningController(model, running_gait, 400.0, 30.0, M1=STABLE_M1, saturate=True,
                             torque_limit=U)
    lib = CompiledRunningLaw.build(out, ctrl, tmp_path / "lib.so")
    X = running_gait.x_stance
    rc, u = lib.torque(0, 0.1, X[:5, 3] + 0.3, X[5:, 3] + 3.0)
    assert rc == 0 and np.max(np.abs(u)) == U
    assert f"clipped at +-{U} N m" in (out / RUNNING_HEADER).read_text()
    M = ["mujoco-running", "--gait", g, "--strides", 2, "--saturate", "--torque-limit", U]
    runs = []
    for extra in (["--json"], ["--json", "--compiled", out]):
        rc, o = run(capsys, *M, *extra)
        runs.append(json.loads(o.out))
        assert runs[-1]["clipped_at"] == U and runs[-1]["torque_limit"] == U
    assert runs[0]["strides"] == runs[1]["strides"] and runs[0]["status"] == "ran"
    assert max(s["peak_torque"] for s in runs[0]["strides"]) == pytest.approx(U, rel=1e-12)
    rc, o = run(capsys, *M)
    assert f"torques clipped at {U:g} N m" in o.out.splitlines()[0]
    assert "the export's torque_limit is 80.0, this run's 150.0" in _bad(
        capsys, *M[:-2], "--compiled", out)
    for extra in (["export-running", "--out", tmp_path / "o"], ["mujoco-running"]):
        err = _bad(capsys, *extra, "--gait", g, "--torque-limit", U)
        assert "--torque-limit is the limit --saturate clips at (add --saturate)" in err
    assert "--torque-limit must be a positive number" in _bad(
        capsys, *M[:-1], "nan")
