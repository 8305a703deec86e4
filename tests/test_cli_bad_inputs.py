"""Every subcommand against the bad inputs a newcomer tries (issue 12): exit code 2, one
line on stderr that names the offending argument or file, nothing on stdout, no
traceback, nothing left behind, no earlier file changed.

Read-only folders and unreadable files: the suite may run as root, for whom permission
bits stop nothing; there the cases marked "nonroot" have the operating system's answer
for those paths (EACCES from open) emulated, and /sys (not writable even for root) is a
real read-only place.
"""
from __future__ import annotations

import copy
import errno
import hashlib
import json
import os
import pathlib
import subprocess
import sys

import pytest

from analysis.cli import main as biped_main
import biped_casadi
from biped_casadi import RobotParams
from analysis.sweeps import grid_points, run_sweep
from gait_opt import GaitFileError

ROOT = hasattr(os, "geteuid") and os.geteuid() == 0
READ_ONLY_SYSTEM = "/sys"          # EACCES on create, also for root


def _sign(body: dict) -> dict:
    """A gait file body with a valid checksum (the format's: SHA-256 of the sorted JSON
    of everything else), as someone editing a file by program would make it."""
    body = dict(body)
    body.pop("sha256", None)
    body["sha256"] = hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()
    return body


@pytest.fixture(scope="module")
def files(model, gait, tmp_path_factory):
    """Named paths (formatted into the arguments of each case)."""
    d = tmp_path_factory.mktemp("bad_inputs")
    good = gait.save(d / "gait.json")
    body = json.loads(good.read_text())
    out = dict(gait=str(good), dir=str(d / "a_folder"), file=str(d / "a_file.txt"),
               missing=str(d / "missing.json"), sys=READ_ONLY_SYSTEM)
    (d / "a_folder").mkdir()
    (d / "a_file.txt").write_text("not a folder\n")
    (d / "a_folder.gif").mkdir()
    out["dir_gif"] = str(d / "a_folder.gif")

    def write(name, text):
        (d / name).write_bytes(text if isinstance(text, bytes) else text.encode())
        out[name.split(".")[0]] = str(d / name)

    def edited(name, edit, sign=True):
        b = copy.deepcopy(body)
        edit(b)
        write(name, json.dumps(_sign(b) if sign else b))

    write("empty.json", "")
    write("garbage.json", bytes(range(256)) * 4)
    write("truncated.json", good.read_text()[:500])
    write("list.json", "[1, 2, 3]")
    write("number.json", "42")
    write("family.json", json.dumps({"format": "biped-casadi-gait-family", "version": 1}))
    write("other_format.json", json.dumps({"format": "something-else", "version": 1}))
    write("deep.json", "[" * 100000 + "]" * 100000)
    write("summary.json", json.dumps({"stages": {}, "figures": {}}))
    edited("version.json", lambda b: b.update(version=99))
    edited("checksum.json", lambda b: b["solution"].update(T=0.7), sign=False)
    edited("no_sha.json", lambda b: b.pop("sha256"), sign=False)
    edited("no_solution.json", lambda b: b.pop("solution"))
    edited("no_x0.json", lambda b: b["solution"].pop("x0"))
    edited("solution_list.json", lambda b: b.update(solution=[1, 2]))
    edited("x0_nan.json", lambda b: b["solution"].update(x0=[float("nan"), 0.0]))
    edited("ragged.json", lambda b: b["solution"]["alpha"][2].pop())
    edited("alpha_size.json", lambda b: b["solution"].update(alpha=[[0.0] * 7] * 3))
    edited("alpha_text.json", lambda b: b["solution"]["alpha"][0].__setitem__(0, "0.1"))
    edited("T_text.json", lambda b: b["solution"].update(T="0.69"))
    edited("T_negative.json", lambda b: b["solution"].update(T=-0.69))
    edited("T_huge.json", lambda b: b["solution"].update(T=1e300))
    edited("T_tiny.json", lambda b: b["solution"].update(T=1e-300))
    edited("open_orbit.json", lambda b: b["solution"].update(T=b["solution"]["T"] * 1.01))
    edited("robot_mass.json", lambda b: b["robot"]["torso"].update(mass=-12.0))
    edited("robot_flat.json", lambda b: b.update(robot=dict(RobotParams().to_dict(),
                                                            m_torso=-12.0)))
    edited("robot_list.json", lambda b: b.update(robot=[1, 2]))
    edited("options_bad.json", lambda b: b["options"].update(speed="fast"))
    edited("options_huge.json", lambda b: b["options"].update(n_intervals=10**7))
    edited("extra_key.json", lambda b: b.update(comment="edited by hand"))
    # the toolkit's other inputs given as a gait: a sampled step, a robot description
    write("step.csv", "t,q1,q2,q3,q4,q5,dq1,dq2,dq3,dq4,dq5\n" + "0,0,0,0,0,0,0,0,0,0,0\n")
    write("step_nodes.json", json.dumps({"t": [0.0], "q": [[0.0] * 5], "dq": [[0.0] * 5]}))
    write("robot_desc.toml", (pathlib.Path(__file__).parent.parent / "biped_casadi" / "model"
                              / "robots" / "rabbit.toml").read_text())
    write("params_garbage.toml", bytes(range(256)))
    write("params_empty.toml", "")
    write("params_bad.json", json.dumps(dict(RobotParams().to_dict(), m_torso=-12.0)))
    write("params_unknown.json", json.dumps({"wings": 2}))
    write("params.txt", "m_torso = 12\n")
    unreadable = d / "unreadable.json"
    unreadable.write_text(good.read_text())
    unreadable.chmod(0)
    out["unreadable"] = str(unreadable)
    ro = d / "read_only"
    ro.mkdir()
    ro.chmod(0o500)
    out["read_only"] = str(ro)
    # a sweep folder made with other settings, and a folder that is not a sweep folder
    run_sweep(gait, grid_points(2, -1.0, 1.0), out_dir=d / "sweep2", progress=False)
    out["sweep2"] = str(d / "sweep2")
    (d / "notes").mkdir()
    (d / "notes" / "todo.txt").write_text("my notes\n")
    out["notes"] = str(d / "notes")
    (d / "broken_link.json").symlink_to(d / "gone.json")
    out["broken_link"] = str(d / "broken_link.json")
    os.mkfifo(d / "pipe.json")
    out["pipe"] = str(d / "pipe.json")
    write("plant_bad.toml", (pathlib.Path(__file__).parent.parent / "biped_casadi" / "model"
                             / "robots" / "rabbit.toml").read_text().replace("mass = 12.0",
                                                                             "mass = -12.0"))
    write("robot_huge.toml", (pathlib.Path(__file__).parent.parent / "biped_casadi" / "model"
                              / "robots" / "rabbit.toml").read_text().replace(
                                  "length = 0.4", "length = 1e300", 1))
    write("terrain_text.txt", "0.01 0.02 zero\n")
    write("terrain_high.json", "[0.01, 0.5]")
    out["long"] = "x" * 5000
    out["root_dir"] = str(d)
    yield out
    unreadable.chmod(0o600)
    ro.chmod(0o700)


G = ["--gait", "{gait}"]
M0 = ["--m1", "0", "0", "0", "0"]
TV = ["--m1", "-10", "7.5", "10", "-5", "--runs", "2", "--max-steps", "2",
      "--scheduler", "inline"]

#: (arguments, a word the error line must contain[, "nonroot" when permissions matter])
CASES = [
    # ---- the command line itself
    ([], "required"),
    (["walk"], "invalid choice"),
    (["eig", "--bogus"], "unrecognized arguments"),
    # ---- model
    (["model", "--q", "1", "2", "3"], "--q takes 5"),
    (["model", "--q", "nan", "0", "0", "0", "0"], "finite"),
    (["model", "--q", "inf", "0", "0", "0", "0"], "finite"),
    (["model", "--q", "abc"], "invalid float"),
    (["model", "--robot", "{missing}"], "not found"),
    (["model", "--robot", "/dev/null"], "not a regular file"),
    (["model", "--robot", "{params_garbage}"], "not a text"),
    (["model", "--robot", "{params_empty}"], "leg is missing"),
    (["model", "--robot", "{params_bad}"], "m_torso"),
    (["model", "--robot", "{params_unknown}"], "unknown robot parameter"),
    (["model", "--robot", "{params}"], ".toml or .json"),
    (["model", "--robot", "{long}.toml"], "--robot"),
    (["model", "--robot", "{dir}"], "is a folder"),
    (["model", "--robot", "octopus"], "neither a built-in robot"),
    # a gait file as the robot: 'unknown robot parameter(s): actuators, gravity, ...'
    (["model", "--robot", "{gait}"], "is a biped-casadi-gait file, not a robot description"),
    (["terrain", *TV, "--plant", "{family}"], "--plant: {family} is a biped-casadi-gait-family "
                                               "file, not a robot"),
    # an empty name (an unset shell variable) meant the default robot or gait
    (["model", "--robot", ""], "--robot: empty name"),
    (["eig", "--gait", "", *M0], "--gait: empty name"),
    (["eig", *G, "--robot", " ", *M0], "--robot: empty name"),
    (["terrain", *TV, "--plant", ""], "--plant: empty name"),
    (["robot", "import", "", "--out", "{root_dir}/r.toml"], "FILE: empty name"),
    (["eig", "--robot", "three_link", *G, *M0], "other robot"),
    (["model", "--robot", "{unreadable}"], "cannot be read", "nonroot"),
    # ---- gait: numbers, then output paths (checked before the 3 s solve)
    (["gait", "--speed", "0"], "--speed"),
    (["gait", "--speed", "-1"], "--speed"),
    (["gait", "--speed", "nan"], "--speed"),
    (["gait", "--speed", "inf"], "--speed"),
    (["gait", "--mu", "0"], "--mu"),
    (["gait", "--torque-limit", "-5"], "--torque-limit"),
    (["gait", "--impact-mu", "-0.1"], "--impact-mu"),
    (["gait", "--continuation", "nan"], "--continuation"),
    (["gait", "--continuation-shape", "smooth"], "--continuation"),
    # a decay time whose closed form overflows (imported: written, then 'not a periodic
    # orbit, |P(x*) - x*| = inf' from biped eig) or loses its digits (0.6 rad at 1e5)
    (["gait", "--continuation", "1e5", "--continuation-shape", "smooth", "--out",
      "{root_dir}/g.json"], "--continuation C, at most 10 (the decay time, in T), got 100000"),
    (["gait", "--import", "{step}", "--continuation", "1e300", "--continuation-shape",
      "smooth", "--out", "{root_dir}/g.json"], "at most 10"),
    (["gait", "--clearance", "-0.01"], "--clearance"),
    (["gait", "--intervals", "2"], "--intervals"),
    (["gait", "--intervals", "100000"], "--intervals"),
    (["gait", "--intervals", "3.5"], "invalid int"),
    (["gait", "--max-iter", "0"], "--max-iter"),
    (["gait", "--scheme", "euler"], "invalid choice"),
    (["gait", "--speed", "5", "--out", "{root_dir}/g5.json"], "no feasible gait"),
    (["gait", "--out", "{dir}"], "--out"),
    # missing folders of an output are created when it is written, unless they cannot be
    (["gait", "--out", "{file}/new/gait.json"], "cannot write {file}/new/gait.json: {file} "
                                                 "is a file, not a folder"),
    (["gait", "--out", "{read_only}/new/gait.json"], "cannot write", "nonroot"),
    (["gait", "--out", "{file}/gait.json"], "is a file"),
    (["gait", "--out", ""], "--out"),
    (["gait", "--out", "/dev/null"], "not a regular file"),
    (["gait", "--out", "{root_dir}/plain"], "--out: the file name must end in .json"),
    (["gait", "--speeds", "0.7:0.8:0.1", "--out", "{root_dir}/fam"], "must end in .json"),
    (["gait", "--out", "{root_dir}/{long}.json"], "--out"),
    (["gait", "--out", "{sys}/gait.json"], "cannot write"),
    (["gait", "--out", "{read_only}/gait.json"], "cannot write", "nonroot"),
    (["gait", "--out", "{root_dir}/g.json", "--plot", "{file}"], "--plot"),
    (["gait", "--out", "{root_dir}/g.json", "--plot", "{file}/figs"], "--plot"),
    (["gait", "--out", "{root_dir}/g.json", "--robot", "{params_garbage}"], "not a text file"),
    # the options of --import and --export-csv without them: ignored before (the gait was
    # optimised and written with exit 0), the solver's with --import likewise
    (["gait", "--nodes", "0", "--out", "{root_dir}/g.json"], "--nodes applies with "
                                                              "--export-csv only"),
    (["gait", "--import-tol", "nan", "--out", "{root_dir}/g.json"], "--import-tol applies"),
    (["gait", "--bezier-degree", "2", "--out", "{root_dir}/g.json"], "--bezier-degree applies"),
    (["gait", "--angles", "absolute", "--out", "{root_dir}/g.json"], "--angles applies with"),
    (["gait", "--import", "{missing}", "--intervals", "60", "--out", "{root_dir}/g.json"],
     "--intervals does not apply with --import"),
    (["gait", "--export-csv", "{root_dir}/g.csv", "--gait", "{gait}", "--max-iter", "5"],
     "--max-iter does not apply with --export-csv"),
    # ---- eig: numbers and options
    (["eig", *G], "--m1 is required for the time-varying controller"),
    (["terrain", "--runs", "2"], "--m1 is required for the time-varying controller (one "
                                 "number per torque: 4 for this robot)"),
    (["eig", *G, "--m1", "1", "2", "3"], "--m1 takes 4"),
    (["eig", *G, "--m1", "1", "2", "3", "4", "5"], "--m1 takes 4"),
    (["eig", *G, "--m1", "nan", "0", "0", "0"], "--m1"),
    (["eig", *G, "--m1", "inf", "0", "0", "0"], "--m1"),
    (["eig", *G, "--m1", "1e300", "0", "0", "0"], "--m1"),
    (["eig", *G, "--m1", "1e7", "0", "0", "0"], "--m1"),
    (["eig", *G, "--m1", "-1e300", "0", "0", "0"], "--m1"),
    (["eig", *G, "--m1", "-inf", "0", "0", "0"], "--m1"),
    (["eig", *G, "--m1", "one", "0", "0", "0"], "invalid float"),
    (["eig", *G], "--m1"),
    (["eig", *G, "--controller", "vc", *M0], "--m1"),
    (["eig", *G, "--controller", "vc", "--method", "ad"], "--method"),
    (["eig", *G, *M0, "--method", "fd"], "invalid choice"),
    (["eig", *G, *M0, "--controller", "hzd"], "invalid choice"),
    # ---- eig: gait files (the same loader serves every command)
    # a missing or broken gait file without --m1: the file named first (eig said "--m1 is
    # required" before; robust and terrain named the file), then --m1 with the count
    (["eig", "--gait", "{missing}"], "gait file not found"),
    (["eig", "--gait", "{truncated}"], "not valid JSON"),
    (["robust", "--gait", "{missing}"], "gait file not found"),
    (["terrain", "--gait", "{truncated}", "--runs", "2"], "not valid JSON"),
    (["eig", *G], "--m1 is required for the time-varying controller (one number per "
                  "torque: 4 for this robot)"),
    (["eig", "--gait", "{missing}", *M0], "not found"),
    (["eig", "--gait", "{dir}", *M0], "is a folder"),
    (["eig", "--gait", "/dev/null", *M0], "not a regular file"),
    (["eig", "--gait", "{empty}", *M0], "is empty"),
    (["eig", "--gait", "{garbage}", *M0], "not a text"),
    (["eig", "--gait", "{truncated}", *M0], "not valid JSON"),
    (["eig", "--gait", "{deep}", *M0], "not valid JSON"),
    (["eig", "--gait", "{list}", *M0], "not a biped-casadi-gait file"),
    (["eig", "--gait", "{number}", *M0], "not a biped-casadi-gait file"),
    (["eig", "--gait", "{other_format}", *M0], "not a biped-casadi-gait file"),
    (["eig", "--gait", "{summary}", *M0], "not a biped-casadi-gait file"),
    # a sampled step or a robot given as the gait: "not valid JSON (truncated or
    # corrupted?)" before; what to do with it instead
    (["eig", "--gait", "{step}", *M0], "{step} is a sampled step, not a gait file: make a "
                                      "gait of it with gait_opt.import_gait (on the command "
                                      "line 'biped gait --import {step} --out gait.json'"),
    (["simulate", "--gait", "{step_nodes}"], "{step_nodes} is a sampled step"),
    (["sweep", "--gait", "{robot_desc}", "--grid", "2"], "{robot_desc} is a robot "
                                                         "description, not a gait file"),
    # a gait family where one gait is taken: how to take one from it
    # an output that is the input: the family was replaced by the one gait taken from it
    (["gait", "--family", "{family}", "--speed", "0.75", "--out", "{family}"],
     "--out: {family} is the --family file; writing there would replace it"),
    (["m1", "--robust", "--gait", "{gait}", "--out", "{gait}"], "--out: {gait} is the --gait"),
    (["eig", "--gait", "{family}", *M0], "--gait: {family} is a gait family file, not one "
                                          "gait: take one with 'biped gait --family"),
    (["simulate", "--gait", "{family}", "--controller", "vc"], "or walk it with --speeds"),
    (["sweep", "--gait", "{family}", "--grid", "2"], "is a gait family file"),
    (["m1", "--gait", "{family}"], "'biped m1 --robust' designs over a family"),
    (["eig", "--gait", "{version}", *M0], "format version 99"),
    # edited by hand: what to do instead ("corrupted (checksum mismatch)" before, also
    # for a file without a checksum)
    (["eig", "--gait", "{checksum}", *M0], "is corrupted or was edited (checksum mismatch):"
                                           " only the numbers the toolkit wrote are read; "
                                           "write the file again, or import a step edited "
                                           "by hand"),
    (["eig", "--gait", "{no_sha}", *M0], "{no_sha} has no 'sha256' checksum: only the "
                                         "numbers"),
    (["eig", "--gait", "{no_solution}", *M0], "missing key(s): solution"),
    (["eig", "--gait", "{no_x0}", *M0], "x0"),
    (["eig", "--gait", "{solution_list}", *M0], "'solution' must be an object"),
    (["eig", "--gait", "{x0_nan}", *M0], "non-finite"),
    (["eig", "--gait", "{ragged}", *M0], "solution.alpha"),
    (["eig", "--gait", "{alpha_size}", *M0], "solution.alpha"),
    (["eig", "--gait", "{alpha_text}", *M0], "only numbers"),
    (["eig", "--gait", "{T_text}", *M0], "solution.T"),
    (["eig", "--gait", "{T_negative}", *M0], "solution.T"),
    (["eig", "--gait", "{T_huge}", *M0], "not a periodic orbit"),
    (["eig", "--gait", "{open_orbit}", *M0], "not a periodic orbit"),
    (["simulate", "--gait", "{T_huge}", "--allow-open-orbit"], "cannot be evaluated"),
    (["eig", "--gait", "{T_tiny}", *M0], "cannot be evaluated"),
    (["eig", "--gait", "{robot_mass}", *M0], "'robot': torso.mass must be positive"),
    (["eig", "--gait", "{robot_flat}", *M0], "m_torso"),
    (["eig", "--gait", "{robot_list}", *M0], "'robot'"),
    (["eig", "--gait", "{options_bad}", *M0], "speed"),
    # read as it was, `gait --family F --resolve` and `m1 --robust --gait F` built an NLP
    # of 10^7 intervals until the memory ran out
    (["eig", "--gait", "{options_huge}", *M0], "'n_intervals' must be at most"),
    (["eig", "--gait", "{extra_key}", *M0], "unknown key(s): comment"),
    (["eig", "--gait", "{unreadable}", *M0], "cannot be read", "nonroot"),
    (["eig", "--gait", "{broken_link}", *M0], "broken link"),
    # a named pipe: the test for a family file opened it and waited for a writer forever
    (["eig", "--gait", "{pipe}", *M0], "not a regular file"),
    (["eig", "--gait", "{long}.json", *M0], "gait file"),
    # ---- sweep
    (["sweep"], "--gait"),
    (["sweep", *G, "--grid", "1"], "--grid"),
    (["sweep", *G, "--grid", "0"], "--grid"),
    (["sweep", *G, "--grid", "-3"], "--grid"),
    (["sweep", *G, "--grid", "100"], "--grid"),
    (["sweep", *G, "--grid", "3", "--line", "3"], "not allowed with"),
    (["sweep", *G, "--line", "1"], "--line"),
    (["sweep", *G, "--range", "10", "-10"], "--range"),
    (["sweep", *G, "--range", "5", "5"], "--range"),
    (["sweep", *G, "--range", "nan", "1"], "--range"),
    (["sweep", *G, "--range", "-1e300", "1e300"], "--range"),
    (["sweep", *G, "--range", "0"], "--range"),
    (["sweep", *G, "--grid", "2", "--plot", "{file}"], "--plot"),
    (["sweep", *G, "--grid", "2", "--workers", "0"], "--workers"),
    (["sweep", *G, "--grid", "2", "--workers", "100000"], "--workers"),
    (["sweep", *G, "--grid", "2", "--chunk-size", "0"], "--chunk-size"),
    (["sweep", *G, "--grid", "2", "--scheduler", "nonsense"], "--scheduler"),
    (["sweep", *G, "--grid", "2", "--out", "{file}"], "--out"),
    (["sweep", *G, "--grid", "2", "--out", "{file}/sweep"], "--out"),
    (["sweep", *G, "--grid", "2", "--out", "{sys}/sweep"], "--out"),
    (["sweep", *G, "--grid", "2", "--out", "{read_only}/sweep"], "--out", "nonroot"),
    (["sweep", *G, "--grid", "3", "--out", "{sweep2}"], "--out: {sweep2} holds a sweep made "
     "with other settings"),
    (["sweep", *G, "--grid", "2", "--out", "{notes}"], "--out: {notes} is not empty"),
    (["sweep", *G, "--line", "3", "--plot", "{file}"], "--plot"),
    (["sweep", "--gait", "{open_orbit}", "--grid", "2"], "not a periodic orbit"),
    # ---- m1
    (["m1", *G, "--free", "--group", "1"], "not allowed with"),
    (["m1", *G, "--group", "3"], "invalid choice"),
    (["m1", *G, "--samples", "1000"], "--robust"),
    (["m1", "--robust", "--method", "search", "--gait", "{gait}"], "--robust"),
    (["m1", "--robust", "--gait", "{missing}"], "not found"),
    (["m1", "--robust", "--method", "bfgs"], "invalid choice"),
    (["m1", "--robust", "--samples", "10"], "--samples"),
    (["m1", "--robust", "--starts", "0"], "--starts"),
    (["m1", "--gait", "{missing}"], "not found"),
    (["m1", "--gait", "{ragged}"], "solution.alpha"),
    # ---- simulate
    (["simulate", *G, "--m1", "1", "2", "3"], "--m1 takes 4"),
    (["simulate", *G, "--m1", "nan", "0", "0", "0"], "--m1"),
    (["simulate", *G, "--m1", "1e300", "0", "0", "0"], "--m1"),
    (["simulate", *G, "--m1", "1.70", "0", "0", "0"], "singular"),
    (["simulate", *G, "--eps", "1e-6"], "need eps >= 0.00069 s at this step"),
    (["simulate", *G, "--controller", "vc", *M0], "--m1"),
    (["simulate", *G, "--steps", "0"], "--steps"),
    (["simulate", *G, "--steps", "-1"], "--steps"),
    (["simulate", *G, "--steps", "100000000"], "--steps"),
    (["simulate", *G, "--steps", "2.5"], "invalid int"),
    (["simulate", *G, "--perturb", "0.1"], "expected 2"),
    (["simulate", *G, "--perturb", "nan", "0"], "--perturb"),
    # errors beyond half a turn / 100 rad/s: overflow and 300-digit angles before
    (["simulate", *G, "--perturb", "1e300", "0"], "--perturb: angle errors must lie within"),
    (["simulate", *G, "--perturb", "0", "1e6"], "--perturb: rate errors must lie within"),
    (["simulate", *G, "--perturb", "-4", "0"], "+-3.14"),
    (["simulate", *G, "--perturb-dq", "1e308", "0", "0", "0", "0"], "--perturb-dq: rate"),
    (["simulate", *G, "--perturb-q", "0", "0", "7", "0", "0"], "--perturb-q: angle"),
    (["mujoco", *G, "--perturb", "1e300", "0"], "--perturb: angle"),
    (["simulate", *G, "--perturb", "0", "0", "--perturb-q", "0", "0", "0", "0", "0"],
     "--perturb"),
    (["simulate", *G, "--perturb-q", "1", "2"], "--perturb-q takes 5"),
    (["simulate", *G, "--perturb-dq", "inf", "0", "0", "0", "0"], "--perturb-dq"),
    (["simulate", *G, "--mu", "0"], "--mu"),
    (["simulate", *G, "--mu", "-1"], "--mu"),
    (["simulate", *G, "--eps", "0"], "--eps"),
    (["simulate", *G, "--eps", "1e-300"], "eps"),
    (["simulate", *G, "--eps", "1e-5"], "eps"),
    (["simulate", *G, "--eps", "1e300"], "'eps' = 1e+300 s is too large"),  # OverflowError
    (["export", *G, "--out", "{root_dir}/law", "--gains", "1", "2", "1e300"], "too large"),
    (["simulate", *G, "--torque-limit", "0"], "--torque-limit"),
    (["simulate", *G, "--animate", "{root_dir}/walk.mp4"], ".gif"),
    (["simulate", *G, "--animate", "{dir_gif}"], "is a folder"),
    (["simulate", *G, "--animate", "{read_only}/new/walk.gif"], "cannot write", "nonroot"),
    (["simulate", *G, "--animate", "{file}/walk.gif"], "is a file"),
    (["simulate", *G, "--animate", "{sys}/walk.gif"], "cannot write"),
    (["simulate", *G, "--plot", "{file}"], "--plot"),
    (["simulate", *G, "--plot", "{sys}/figs"], "--plot"),
    (["simulate", *G, "--plot", "{read_only}/figs"], "--plot", "nonroot"),
    (["simulate", "--gait", "{garbage}"], "not a text"),
    # taken as given and ignored before: the virtual constraints have no rejoin time
    (["simulate", *G, "--controller", "vc", "--rejoin", "0.3"], "--rejoin applies to the "
                                                                "time-varying controller"),
    # --perturb-q of another robot's length: export wrote the law with exit 0 (only
    # --verify used it)
    (["export", *G, "--out", "{root_dir}/law", "--perturb-q", "0", "0"],
     "--perturb-q takes 5 numbers"),
    # ---- robust: a singular design is refused as simulate refuses it (not "slipped")
    # numpy's 'expected non-negative integer' was the whole line
    (["robust", *G, *M0, "--seed", "-1"], "--seed must be >= 0, got -1"),
    (["robust", *G, "--controller", "vc", "--steps", "ten"],
     "--steps must be a whole number of steps or 'auto'"),
    (["robust", *G, "--controller", "vc", "--steps", "0"],
     "--steps must be between 1 and 1000, got 0"),
    (["m1", "--robust", "--method", "search", "--seed", "-1"], "--seed must be >= 0"),
    (["robust", *G, "--m1", "1", "2", "3", "4"], "makes the controller singular"),
    (["robust", *G, "--m1", "1", "2", "3", "4", "--plot", "figs"], "singular"),
    # ---- robot mjcf: the motors' limit named as the option (inf said "RABBIT has no
    # finite torque limit", nan and -5 "torque_limit must be ...")
    (["robot", "mjcf", "--out", "{root_dir}/m.xml", "--torque-limit", "inf"],
     "--torque-limit must be a positive number, got inf"),
    (["robot", "mjcf", "--out", "{root_dir}/m.xml", "--torque-limit", "nan"],
     "--torque-limit must be a positive number"),
    (["robot", "mjcf", "--out", "{root_dir}/m.xml", "--torque-limit", "-5"],
     "--torque-limit must be a positive number"),
    # a foot larger than the leg, a friction MuJoCo overflows on: a walk that fell or
    # diverged (exit 1) and an MJCF written with exit 0 before
    (["mujoco", *G, "--foot-radius", "100", "--steps", "2", "--no-eig"],
     "--foot-radius must be smaller than the leg's last link (0.4 m"),
    (["robot", "mjcf", "--out", "{root_dir}/m.xml", "--foot-radius", "0.5"],
     "--foot-radius must be smaller"),
    (["robot", "mjcf", "--out", "{root_dir}/m.xml", "--cone", "conical"],
     "argument --cone: invalid choice: 'conical'"),
    (["mujoco", *G, "--mu", "1e300", "--steps", "2", "--no-eig"], "--mu must be at most"),
    # the contact's time constant: a word other than 'auto', below two time steps, not a
    # positive number, longer than a walking step (1e300 walked, slipped, and the softer
    # contacts the check tried were 1.5e300 and 2e300 s)
    (["mujoco", *G, "--solref", "soft"], "--solref: a time constant in seconds or 'auto'"),
    (["mujoco", *G, "--solref", "0.003"], "--solref must be at least two time steps"),
    (["mujoco", *G, "--solref", "0.004", "--timestep", "0.01", "--contact", "stiff"],
     "--solref must be at least two time steps"),
    (["mujoco", *G, "--solref", "-0.01"], "--solref must be a positive time constant"),
    (["mujoco", *G, "--solref", "nan"], "--solref must be a positive time constant"),
    (["mujoco", *G, "--solref", "1e300"], "--solref must be at most 1 s"),
    (["robot", "mjcf", "--out", "{root_dir}/m.xml", "--solref", "auto"], "--solref"),
    # ---- reproduce (checked before the first stage)
    (["reproduce", "--out", "{file}"], "--out"),
    (["reproduce", "--quick", "--out", "{file}"], "--out"),
    (["reproduce", "--out", "{file}/rep"], "--out"),
    # ---- terrain (issue 22)
    (["terrain", *TV, "--sigma", "-0.01"], "--sigma"),
    (["terrain", *TV, "--sigma", "nan"], "--sigma"),
    (["terrain", *TV, "--sigma", "inf"], "--sigma"),
    (["terrain", *TV, "--sigma", "1"], "--sigma"),
    (["terrain", *TV, "--runs", "0"], "--runs"),
    (["terrain", *TV, "--runs", "1000000000"], "--runs"),
    (["terrain", *TV, "--max-steps", "0"], "--max-steps"),
    (["terrain", *TV, "--max-steps", "1000000000"], "--max-steps"),
    (["terrain", *TV, "--chunk", "0"], "--chunk"),
    (["terrain", *TV, "--seed", "-1"], "--seed"),
    (["terrain", *TV, "--terrain", "{missing}"], "--terrain"),
    (["terrain", *TV, "--terrain", "{dir}"], "--terrain"),
    (["terrain", *TV, "--terrain", "{garbage}"], "--terrain"),
    (["terrain", *TV, "--terrain", "{empty}"], "no height"),
    (["terrain", *TV, "--terrain", "{terrain_text}"], "not a number"),
    (["terrain", *TV, "--terrain", "{terrain_high}"], "at most"),
    (["terrain", *TV, "--terrain", "{truncated}"], "malformed"),
    (["terrain", *TV, "--terrain", "{unreadable}"], "--terrain", "nonroot"),
    (["terrain", *TV, "--terrain", "{list}", "--sigma", "0.01"], "excludes"),
    (["terrain", *TV, "--plant", "{missing}"], "--plant"),
    (["terrain", *TV, "--plant", "{dir}"], "--plant"),
    (["terrain", *TV, "--plant", "{params_garbage}"], "--plant"),
    (["terrain", *TV, "--plant", "{plant_bad}"], "--plant"),
    (["terrain", *TV, "--plant", "three_link"], "not a plant of this robot"),
    (["terrain", *TV, "--plant", "octopus"], "--plant"),
    (["terrain", *TV, "--mass-scale", "0"], "--mass-scale"),
    (["terrain", *TV, "--inertia-scale", "-1"], "--inertia-scale"),
    (["terrain", *TV, "--length-scale", "nan"], "--length-scale"),
    (["terrain", *TV, "--torso-mass-scale", "inf"], "--torso-mass-scale"),
    (["terrain", *TV, "--plant", "rabbit", "--mass-scale", "1.1"], "excludes"),
    # a plant scaled beyond the description's range: the option named (the line was
    # '--scaled robot: ...-scale: scaled robot: ...')
    (["terrain", *TV, "--length-scale", "1e200"], "error: --length-scale: scaled robot: "
                                                  "torso.length must be at most"),
    (["model", "--robot", "{robot_huge}"], "leg[1].length must be at most 1e+06"),
    (["terrain", *TV, "--gains", "1", "2", "0"], "--gains"),
    (["terrain", "--m1", "1", "2"], "--m1 takes 4"),
    (["terrain", "--controller", "vc", "--m1", "1", "2", "3", "4"], "--m1"),
    (["terrain", *TV, "--scheduler", "nonsense"], "--scheduler"),
    (["terrain", *TV, "--scheduler", "tcp://127.0.0.1:1", "--out", "{root_dir}/mc"],
     "--scheduler"),
    (["terrain", *TV, "--out", "{file}"], "--out"),
    (["terrain", *TV, "--plot", "{file}/figs"], "--plot"),
    (["simulate", "--terrain", "nan"], "--terrain"),
    (["simulate", "--terrain", "0.01", "1.0"], "--terrain"),
    # a scheduler that does not answer: every stage's failure (21 lines) and an empty
    # output folder left behind before
    (["reproduce", "--quick", "--scheduler", "nonsense", "--out", "{root_dir}/rep"],
     "--scheduler: cannot connect to the Dask scheduler at nonsense"),
    (["reproduce", "--scheduler", " ", "--out", "{root_dir}/rep"], "--scheduler: empty address"),
    (["m1", "--robust", "--scheduler", "nonsense"], "--scheduler: cannot connect"),
    # a sweep asked for the scheduler only for its chunks: a nested line repeated after
    # its timeout, and its --out folder (sweep.json, log, chunks) left behind
    (["sweep", "--gait", "{gait}", "--grid", "3", "--scheduler", "nonsense", "--out",
      "{root_dir}/sw"],
     "--scheduler: cannot connect to the Dask scheduler at nonsense"),
    # a local cluster of 100000 processes was started
    (["reproduce", "--workers", "100000", "--out", "{root_dir}/rep"], "--workers: must be "
                                                                     "between 1 and 64"),
    (["reproduce", "--out", ""], "--out"),
    (["reproduce", "--out", "{sys}/rep"], "--out"),
    (["reproduce", "--out", "{read_only}/rep", "--quick"], "--out", "nonroot"),
]


def _snapshot(*folders) -> dict:
    """Every file under ``folders`` with its size and modification time, and every
    folder (whose own time changes when a write test creates and removes a file)."""
    out = {}
    for folder in folders:
        for dirpath, dirnames, filenames in os.walk(folder):
            for n in dirnames:
                out[os.path.join(dirpath, n)] = "folder"
            for n in filenames:
                p = os.path.join(dirpath, n)
                try:
                    st = os.stat(p)
                except OSError:
                    continue
                out[p] = (st.st_size, st.st_mtime_ns)
    return out


def _deny_like_permissions(monkeypatch, read_only, unreadable):
    """As root: answer EACCES, as the permission bits would for anyone else, when a file
    is created under ``read_only`` or ``unreadable`` is opened."""
    def denied(path, write):
        p = os.path.abspath(os.fspath(path))
        return p == unreadable or (write and p.startswith(read_only + os.sep))

    real_os_open, real_path_open = os.open, pathlib.Path.open

    def os_open(path, flags, *a, **k):
        if denied(path, flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT)):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), os.fspath(path))
        return real_os_open(path, flags, *a, **k)

    def path_open(self, mode="r", *a, **k):
        if denied(self, any(c in mode for c in "wax+")):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(self))
        return real_path_open(self, mode, *a, **k)

    monkeypatch.setattr(os, "open", os_open)
    monkeypatch.setattr(pathlib.Path, "open", path_open)


def _id(case) -> str:
    return " ".join(case[0])[:60] or "(no arguments)"


def test_an_output_file_in_missing_folders_creates_them_when_written(tmp_path, capsys):
    """As an output folder (``biped export --out a/b/law``), an output file's missing
    folders are created, when it is written: a refused command creates none."""
    out = tmp_path / "new" / "deeper" / "m.xml"
    assert biped_main(["robot", "mjcf", "--out", str(out), "--foot-radius", "0.5"]) == 2
    assert "--foot-radius" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()
    assert biped_main(["robot", "mjcf", "--out", str(out)]) == 0
    assert out.is_file() and str(out) in capsys.readouterr().out


@pytest.mark.parametrize("case", CASES, ids=[_id(c) for c in CASES])
def test_bad_input_is_one_line_and_exit_2(case, files, tmp_path, monkeypatch, capsys):
    args, expect, *flags = case
    if "nonroot" in flags and ROOT:
        _deny_like_permissions(monkeypatch, files["read_only"], files["unreadable"])
    monkeypatch.chdir(tmp_path)
    argv = [a.format(**files) for a in args]
    before = _snapshot(files["root_dir"], tmp_path)
    rc = biped_main(argv)
    cap = capsys.readouterr()
    lines = cap.err.strip().splitlines()
    assert rc == 2, (argv, cap.err, cap.out[:500])
    assert cap.out == "", cap.out[:500]
    assert len(lines) == 1, cap.err
    assert "Traceback" not in cap.err
    assert lines[0].startswith("biped"), lines[0]
    assert expect.format(**files) in lines[0], lines[0]
    assert _snapshot(files["root_dir"], tmp_path) == before, "a file was written or changed"


def test_debug_lets_a_library_value_error_through(files, monkeypatch, capsys):
    """BIPED_DEBUG=1 showed the traceback of every failure but a ValueError: a library's
    ValueError from a bug ('p must be finite' of `biped export --verify` on a slow gait)
    stayed one line, with no way to see where it came from.  A UserError (the command
    line's own check) stays one line."""
    monkeypatch.setenv("BIPED_DEBUG", "1")
    with pytest.raises(GaitFileError, match="checksum"):
        biped_main(["eig", "--gait", files["checksum"], *M0])
    assert biped_main(["eig", "--gait", files["gait"], "--m1", "1", "2"]) == 2
    assert "--m1 takes 4" in capsys.readouterr().err


@pytest.fixture(scope="module")
def run_files(files, running_gait):
    """A running step (RABBIT, 1.5 m/s, from the cache) and edited copies, beside the
    walking gait's files."""
    d = pathlib.Path(files["root_dir"]) / "running"
    d.mkdir(exist_ok=True)
    good = running_gait.save(d / "run.json")
    body = json.loads(good.read_text())
    out = dict(files, run=str(good))

    def edited(name, edit):
        b = copy.deepcopy(body)
        edit(b)
        (d / f"{name}.json").write_text(json.dumps(b))
        out[name] = str(d / f"{name}.json")

    edited("run_nan", lambda b: b["x_stance"][0].__setitem__(0, float("nan")))
    edited("run_inf_u", lambda b: b["u_flight"][1].__setitem__(3, float("inf")))
    edited("run_rows", lambda b: b.update(x_stance=b["x_stance"][:7]))
    edited("run_cols", lambda b: b.update(x_stance=[r[:5] for r in b["x_stance"]]))
    edited("run_T_huge", lambda b: b.update(T_stance=1e300))
    edited("run_T_text", lambda b: b.update(T_stance="0.3"))
    edited("run_step_nan", lambda b: b.update(step_length=float("nan")))
    edited("run_x_empty", lambda b: b.update(x_stance=[]))
    edited("run_three_link", lambda b: b.update(robot="three_link"))
    edited("run_no_options", lambda b: b.pop("options"))
    edited("run_options_list", lambda b: b.update(options=[1, 2]))
    edited("run_extra_key", lambda b: b.update(surprise=1))
    edited("run_extra_option", lambda b: b["options"].update(surprise=1))
    (d / "not_a_table.csv").write_bytes(b"t,q1\r0,1\n")       # a stray carriage return
    out["not_a_table"] = str(d / "not_a_table.csv")
    return out


RG = ["--gait", "{run}"]

#: (arguments, a word the error line must contain): running steps, and walking gaits where
#: running steps are taken (each refused before the closed loop is built)
RUNNING_CASES = [
    # a file of NaN states analysed its closed loop ('state not finite', exit 0); shapes of
    # another robot failed inside CasADi; 1e300 s overflowed; text and an empty table
    # were internal errors; NaN step length and cost were taken
    (["running", "--gait", "{run_nan}"], "'x_stance' has non-finite entries"),
    (["running", "--gait", "{run_inf_u}"], "'u_flight' has non-finite entries"),
    (["mujoco-running", "--gait", "{run_nan}"], "'x_stance' has non-finite entries"),
    (["running", "--gait", "{run_rows}"], "'x_stance' must have 2 nq rows"),
    (["running", "--gait", "{run_cols}"], "has shape"),
    (["running", "--gait", "{run_T_huge}"], "outside the problem's bounds"),
    (["mujoco-running", "--gait", "{run_T_huge}"], "outside the problem's bounds"),
    (["running", "--gait", "{run_T_text}"], "'T_stance' must be a positive number"),
    (["running", "--gait", "{run_step_nan}"], "'step_length' must be a positive number"),
    (["running", "--gait", "{run_x_empty}"], "'x_stance' must be a table"),
    (["running", "--gait", "{run_three_link}"], "not a running step of three_link"),
    # keys missing, unknown or of the wrong type were Python's own words ("KeyError:
    # 'options'", "AttributeError: 'list' object has no attribute 'items'", "TypeError:
    # RunningGait.__init__() got an unexpected keyword argument 'surprise'")
    (["running", "--gait", "{run_no_options}"], "a malformed running gait (missing key(s) "
                                                "'options')"),
    (["running", "--gait", "{run_options_list}"], "('options' must be an object, got [1, 2])"),
    (["running", "--gait", "{run_extra_key}"], "(unknown key(s) 'surprise')"),
    (["mujoco-running", "--gait", "{run_extra_option}"], "(unknown option(s) 'surprise')"),
    # a walking gait where a running step is taken, and the reverse
    (["running", "--gait", "{gait}"], "is a walking gait (from 'biped gait'), not a running "
                                      "step"),
    (["mujoco-running", "--gait", "{family}"], "is a walking gait family"),
    (["eig", "--gait", "{run}", *M0], "is a running step (from 'biped running'), not a "
                                      "walking gait"),
    (["mujoco", "--gait", "{run}", "--controller", "vc"], "is a running step"),
    # options: ignored (--no-cache), taken beyond the model's range or without bound
    (["running", *RG, "--no-cache"], "--no-cache is for optimising one"),
    # an optimisation option given its default value was taken silently (the saved step
    # may be of another speed, grid or output file)
    (["running", *RG, "--speed", "1.5"], "--speed is for optimising one"),
    (["running", *RG, "--intervals", "16", "10", "--out", "running.json"],
     "--intervals, --out are for optimising one"),
    (["running", *RG, "--m1", "1e300", "0", "0", "0"], "--m1: components must lie within"),
    (["running", *RG, "--steps", "100000"], "--steps must be between 0 and 5000"),
    (["running", "--stability", "--perturb", "1e300"], "--perturb must be a finite number "
                                                       "within +-100 rad/s"),
    (["mujoco-running", *RG, "--foot-radius", "10"], "--foot-radius must be smaller"),
    # MuJoCo's time step and contact bounds said "a walking step" in a running command
    (["mujoco-running", *RG, "--timestep", "1"], "--timestep must be at most 0.05 s (a "
                                                 "step, walking or running, lasts a few"),
    (["mujoco-running", *RG, "--timestep", "1e-6"], "(half a second of walking or running "
                                                    "would take"),
    (["mujoco-running", *RG, "--solref", "2"], "--solref must be at most 1 s (longer than "
                                               "a step, walking or running)"),
    # IPOPT ending in failure: CasADi's assertion text ('Error in Opti::solve ... Solver
    # failed ...') and, here, its evaluation warnings on stderr
    (["running", "--speed", "1e300", "--intervals", "2", "2", "--no-cache", "--out",
      "{root_dir}/r.json"], "the running step did not converge at 1e+300 m/s (IPOPT: "
                            "Invalid_Number_Detected"),
    # csv's own error with its advice on newline modes was an internal error
    (["gait", "--import", "{not_a_table}", "--out", "{root_dir}/g.json"],
     "not a CSV table (line 1: new-line character seen in unquoted field)"),
]


@pytest.mark.parametrize("case", RUNNING_CASES, ids=[_id(c) for c in RUNNING_CASES])
def test_bad_running_input_is_one_line_and_exit_2(case, run_files, tmp_path, monkeypatch,
                                                   capsys):
    test_bad_input_is_one_line_and_exit_2(case, run_files, tmp_path, monkeypatch, capsys)


@pytest.mark.parametrize("gains", [["--kp", "1e300"], ["--kd", "1e300"],
                                   ["--kp", "1e9", "--law", "computed_torque"]])
def test_running_gains_too_stiff_for_any_step_are_refused_before_optimising(
        gains, tmp_path, monkeypatch, capsys):
    """Gains whose closed loop diverges at every RK4 step an optimised step can have were
    refused only after the optimisation (about 35 s), by the check at its nodes."""
    import analysis.cli.running as running

    def optimise(*args, **kwargs):
        raise AssertionError("optimised")

    monkeypatch.setattr(running, "optimize_running", optimise)
    assert biped_main(["running", *gains, "--out", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"biped running: error: {gains[0]} {float(gains[1]):g} (above ")
    assert "whatever step is optimised: a step is at least" in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args", [
    ["gait", "--out", "{dir}"],
    ["eig", "--gait", "{ragged}", "--m1", "0", "0", "0", "0"],
    ["sweep", "--gait", "{gait}", "--grid", "2", "--out", "{file}/sweep"],
])
def test_bad_input_in_a_fresh_process(args, files, tmp_path):
    """The installed entry point behaves the same: exit 2, one line, no traceback."""
    r = subprocess.run([sys.executable, "-m", "analysis.cli", *[a.format(**files) for a in args]],
                       capture_output=True, text=True, cwd=tmp_path, timeout=300,
                       env=dict(os.environ, MPLBACKEND="Agg"))
    assert r.returncode == 2, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr, r.stderr
    assert r.stdout == "" and list(tmp_path.iterdir()) == []


def _disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


class _FullStream:
    """A standard output on a full disk: the write fails at once, or (buffered, as a file
    is) when flushed."""

    def __init__(self, buffered: bool):
        self.buffered = buffered

    def write(self, text):
        if not self.buffered:
            _disk_full()
        return len(text)

    def flush(self):
        if self.buffered:
            _disk_full()

    def isatty(self):
        return False


@pytest.mark.parametrize("buffered", [False, True])
def test_a_full_disk_names_the_standard_output(buffered, monkeypatch, capsys):
    """'No space left on device' said which output failed: none when it was stdout (or
    nothing at all when the write was buffered until the interpreter's exit)."""
    monkeypatch.setattr(sys, "stdout", _FullStream(buffered))
    rc = biped_main(["model", "--json"])
    assert (rc, capsys.readouterr().err) == (
        2, "biped model: error: stdout: No space left on device\n")


def test_a_full_disk_names_the_output_file(tmp_path, monkeypatch, capsys):
    """A write that fails for want of space names the file it was writing (not its
    temporary file, and not nothing), and leaves nothing behind."""
    urdf = pathlib.Path(biped_casadi.__file__).parent / "model" / "robots" / "rabbit.urdf"
    out = tmp_path / "robot.toml"
    monkeypatch.setattr(os, "fsync", _disk_full)
    rc = biped_main(["robot", "import", str(urdf), "--out", str(out)])
    assert (rc, capsys.readouterr().err) == (
        2, f"biped robot: error: {out}: No space left on device\n")
    assert list(tmp_path.iterdir()) == []
