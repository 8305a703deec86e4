"""``biped view`` without a browser: the 3-D poses are the model's points, the readout is
``biped eig``'s and the walk ``biped simulate``'s for the same design, the sliders reach
across the stability boundary, a kept basin is found by its task key, the page's
controls drive the same computations, and the command's errors are one line.
(tests/test_view_browser.py loads the page in Chromium.)"""
from __future__ import annotations

import importlib.util
import json
import shlex
import socket
import subprocess
import sys
import threading
import time
import urllib.request

import numpy as np
import pytest

from analysis import poincare_eigenvalues
from analysis.cli import main as biped_main
from analysis.view import (DEPTH, Explorer, ViewSettings, axis_ranges, segment_frames,
                           slider_space, walk_poses)
from analysis.view.space import SCAN_HALF_WIDTH, SCAN_POINTS
from biped_casadi import Design, Perturbation, SimulationOptions, simulate

START = (-10.0, 7.5, 10.0, -5.0)
needs_viser = pytest.mark.skipif(importlib.util.find_spec("viser") is None,
                                 reason="needs the extra 'view' (viser)")


@pytest.fixture(scope="module")
def explorer(gait, tmp_path_factory):
    settings = ViewSettings(gait, M1=START, options=SimulationOptions(steps=10))
    return Explorer(settings, cache=False)


def _rotate(q, v):
    """v rotated by the unit quaternion q = (w, x, y, z)."""
    w, u = q[0], np.asarray(q[1:])
    return v + 2 * w * np.cross(u, v) + 2 * np.cross(u, np.cross(u, v))


def test_segment_frames_span_their_segments(rng):
    a, b = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    b[0] = a[0] - (0, 0, 1.0)                           # straight down: the special case
    pos, wxyz, length = segment_frames(a, b)
    assert np.allclose(np.linalg.norm(wxyz, axis=1), 1, atol=1e-12)
    for i in range(len(a)):
        half = _rotate(wxyz[i], np.array([0, 0, length[i] / 2]))
        assert np.allclose(pos[i] - half, a[i], atol=1e-12)
        assert np.allclose(pos[i] + half, b[i], atol=1e-12)


def test_poses_are_the_robots_points_and_the_feet_stay_put(gait, model):
    q0, dq0 = Perturbation.uniform(5, 0.001, 0.01).initial_state(gait)
    res = simulate(Design.tv(gait, START).controller_for(), q0, dq0,
                   SimulationOptions(steps=3))
    poses = walk_poses(res, model)
    k = res.t.size // 2
    P = np.array(model.points(res.q[k]))
    names = model.point_names
    for role, chain in (("stance", model.stance_chain), ("swing", model.swing_chain)):
        side = DEPTH * (-1) ** res.step[k] * (1 if role == "stance" else -1)
        for p in chain:
            got = poses.joints[f"{role}_{names[p]}"][2][k]
            assert np.allclose(got, (P[0, p] + res.stance_x[k], side, P[1, p]), atol=1e-12)
    # the stance foot stands on its footprint, on its leg's side, during its whole step
    foot = poses.joints["stance_foot_st"][2]
    for s in range(res.step.max() + 1):
        on = res.step == s
        assert np.allclose(foot[on], poses.footprints[s], atol=1e-9)
    assert len(poses.footprints) == len(res.steps) + 1
    # each link keeps its length
    for seg in poses.segments.values():
        length = np.linalg.norm(seg.b - seg.a, axis=1)
        assert np.ptp(length) < 1e-9
    assert poses.index(-1.0) == 0 and poses.index(1e9) == res.t.size - 1
    i = poses.index(res.steps[0].t_impact)
    assert res.step[i] == 1                             # after the impact at that time


def _eig_cli(M1, capsys) -> list:
    assert biped_main(["eig", "--m1", *map(repr, M1)]) == 0
    return capsys.readouterr().out.splitlines()


@pytest.mark.parametrize("M1", [START, (-9.5, 7.6, 10.1, -4.5), (0.0, 0.0, 0.0, 0.0)])
def test_readout_is_what_biped_eig_prints(explorer, gait, M1, capsys):
    lines = explorer.readout("tv", M1).splitlines()
    cli = _eig_cli(M1, capsys)
    r = poincare_eigenvalues(gait, M1)
    value, status = lines[0].split("   status: ")
    assert f"max|lambda| = {value}" in cli and status == r.status
    assert lines[1] in cli and lines[1].startswith("eigenvalues: ")
    assert lines[2] == f"M1 = {list(M1)}"
    assert float(value) == pytest.approx(r.max_abs, rel=1e-7)


def test_readout_of_singular_and_vc(explorer, capsys):
    lines = explorer.readout("tv", (1.7, 0.0, 0.0, 0.0)).splitlines()
    assert lines[0] == "inf   status: singular"
    vc = explorer.readout("vc").splitlines()
    assert biped_main(["eig", "--controller", "vc", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert vc[0] == f"{r['eigenvalue']:.8g}   status: {r['status']}"


@pytest.mark.parametrize("controller, M1", [("tv", START), ("tv", (-9.5, 7.5, 10.0, -5.0)),
                                            ("vc", None)])
def test_walk_is_what_its_replay_command_gives(explorer, controller, M1, capsys):
    w = explorer.walk(controller, M1)
    replay = shlex.split(explorer.replay(controller, M1))
    assert replay[:2] == ["biped", "simulate"]
    rc = biped_main([*replay[1:], "--json"])
    sim = json.loads(capsys.readouterr().out)
    assert rc == (0 if sim["status"] == "ok" else 1)      # a stopped walk exits 1
    first = w.text.splitlines()[0]
    assert first.split(":")[0] == sim["status"] == w.result.status
    if sim["status"] != "ok":
        assert first == f"{sim['status']}: {sim['message']}"
    else:
        assert first.startswith(f"ok: {sim['n_steps']} of {sim['n_steps']} steps valid")
    shown = np.array([np.nan if v is None else v for v in sim["qu_error"]])
    np.testing.assert_array_equal(shown, w.result.qu_error)        # the same run, bit for bit


def test_singular_design_is_not_walked(explorer):
    w = explorer.walk("tv", (1.7, 0.0, 0.0, 0.0))
    assert w.result is None and w.poses is None and w.text.startswith("not walked")


def test_sliders_cross_the_stability_boundary(gait, tmp_path):
    ranges, stable = axis_ranges(gait, START)
    step = 2 * SCAN_HALF_WIDTH / (SCAN_POINTS - 1)
    for j, ((lo, hi), (a, b)) in enumerate(zip(ranges, stable)):
        assert lo < a <= START[j] <= b < hi
        for v, want in ((a, "stable"), (b, "stable"), (a - step, "unstable"),
                        (b + step, "unstable")):
            M1 = np.array(START)
            M1[j] = v
            assert poincare_eigenvalues(gait, M1).status == want, (j, v)
    kept = slider_space(gait, START, cache=True)
    again = slider_space(gait, START, cache=True)          # read back from the cache
    assert again == kept and kept.ranges == ranges and kept.M1 == START


@pytest.mark.slow
def test_a_kept_basin_is_found_and_shown(gait, tmp_path, monkeypatch):
    from analysis.reporting.plots.images import basin_image
    from analysis.robustness import basin_to_boundary
    from analysis.tasks import Engine, ResultStore
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path))
    ex = Explorer(ViewSettings(gait, M1=START), cache=False)
    ex.basin_sizes = (5,)                          # a small basin, as the reproduction keeps
    d = Design.tv(gait, START)
    assert ex.basin("tv", START) is None
    with Engine(scheduler="synchronous", cache=tmp_path) as eng:
        b = eng.submit(basin_to_boundary, d, 5, refine=4).result()
    found = ex.basin("tv", START, store=ResultStore(tmp_path))
    assert found is not None and found.to_dict() == b.to_dict()
    assert ex.basin("vc") is None
    img = basin_image(found)
    assert img.ndim == 3 and img.shape[2] == 3 and min(img.shape[:2]) > 100
    if importlib.util.find_spec("viser") is None:
        return
    from analysis.view import ViewApp
    app = ViewApp(ex, port=0)
    try:
        _until(lambda: app.basin_panel is not None)
        assert b.message in app.basin_note.content
    finally:
        app.stop()


# ------------------------------------------------------------------ the page, headless
def _until(fn, timeout=60.0):
    end = time.monotonic() + timeout
    while not fn():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.05)


@needs_viser
def test_the_controls_drive_the_readout_and_the_walk(explorer, capsys):
    from analysis.view import ViewApp
    app = ViewApp(explorer, port=0)
    try:
        with urllib.request.urlopen(app.url, timeout=30) as page:      # the bundled client
            assert b"<html" in page.read(2000).lower()
        _until(lambda: f"M1 = {list(START)}" in app.walk_box.value
               and app.walk is not None)
        assert [s.label for s in app.sliders] == ["M1[1]", "M1[2]", "M1[3]", "M1[4]"]
        M1 = (-9.5, 7.5, 10.0, -5.0)
        app.sliders[0].value = M1[0]                 # as a client would: the callbacks run
        assert app.eig_box.value == explorer.readout("tv", M1)
        app.walk_button.value = True                 # (a server-side click)
        app.request_walk()
        _until(lambda: f"M1 = {list(M1)}" in app.walk_box.value
               and not app.walk_box.value.startswith("walking"))
        assert app.walk_box.value == explorer.walk("tv", M1).text
        app.controller_box.value = "vc"
        assert all(s.disabled for s in app.sliders)
        _until(lambda: "virtual constraints" in app.walk_box.value
               and not app.walk_box.value.startswith("walking"))
        app.time.value = 1.0                         # the clock draws the robot
        assert app.walk.poses.index(1.0) > 0
    finally:
        app.stop()


@needs_viser
def test_walks_replaced_while_the_clock_draws(explorer, capfd):
    """A new walk (another number of instants) replaces the robot while the clock and a
    user move the time: no instant of one walk is drawn with the other's frames."""
    from analysis.view import ViewApp
    app = ViewApp(explorer, port=0)
    stop = time.monotonic() + 2.0

    failures = []

    def scrub():                                     # as the slider's callback does
        rng = np.random.default_rng(1)
        while time.monotonic() < stop:
            app.time.value = round(float(rng.uniform(0, 8.0)), 2)   # any walk's length
            try:
                app._on_time()
            except Exception as e:                   # noqa: BLE001 - counted
                failures.append(e)
    t = threading.Thread(target=scrub)
    t.start()
    try:
        for M1 in [(-11.0, 7.5, 10.0, -5.0), START, (-9.5, 7.5, 10.0, -5.0), START]:
            app.sliders[0].value = M1[0]
            app.request_walk()
            _until(lambda: f"M1 = {list(M1)}" in app.walk_box.value
                   and not app.walk_box.value.startswith("walking"))
    finally:
        t.join()
        app.stop()
    assert not failures, failures[:3]
    assert "error" not in capfd.readouterr().err and "error" not in app.eig_box.value


def test_three_link_biped(gait3, capsys):
    """nu = 2: two sliders; the readout and the walk as the commands give them."""
    ex = Explorer(ViewSettings(gait3, controller="vc", replay=("--robot", "three_link")),
                  cache=False)
    M1 = ex.space.M1
    assert len(M1) == 2 and len(ex.space.ranges) == 2
    assert biped_main(["eig", "--robot", "three_link", "--m1", *map(repr, M1)]) == 0
    cli = capsys.readouterr().out.splitlines()
    lines = ex.readout("tv", M1).splitlines()
    assert f"max|lambda| = {lines[0].split()[0]}" in cli and lines[1] in cli
    w = ex.walk("tv", M1)
    assert biped_main([*shlex.split(ex.replay("tv", M1))[1:], "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["status"] == w.result.status
    if importlib.util.find_spec("viser") is None:
        return
    from analysis.view import ViewApp
    app = ViewApp(ex, port=0)
    try:
        assert [s.label for s in app.sliders] == ["M1[1]", "M1[2]"]
        assert all(s.disabled for s in app.sliders)          # virtual constraints first
        _until(lambda: "virtual constraints" in app.walk_box.value
               and not app.walk_box.value.startswith("walking"))
        assert len(app.walk.poses.segments) == 4              # one link per leg, torso, axle
    finally:
        app.stop()


# ------------------------------------------------------------------ the command line
@pytest.mark.parametrize("args, expect", [
    (["--port", "70000"], "--port"),
    (["--port", "-1"], "--port"),
    (["--steps", "0"], "--steps"),
    (["--m1", "1", "2"], "--m1 takes 4"),
    (["--m1", "nan", "0", "0", "0"], "--m1"),
    (["--m1", "1.7", "0", "0", "0"], "singular"),
    (["--perturb", "nan", "0"], "--perturb"),
    (["--perturb-q", "0.1"], "--perturb-q takes 5"),
    (["--perturb", "0", "0", "--perturb-q", "0", "0", "0", "0", "0"], "--perturb"),
    (["--rejoin", "2"], "--rejoin"),
    (["--mu", "0"], "--mu"),
    (["--host", "192.0.2.1"], "--host"),
    (["--host", " "], "--host"),
    (["--controller", "pd"], "invalid choice"),
    (["--robot", "octopus"], "neither a built-in robot"),
])
def test_bad_options_are_one_line_and_exit_2(args, expect, capsys):
    assert biped_main(["view", *args]) == 2
    cap = capsys.readouterr()
    lines = cap.err.strip().splitlines()
    assert cap.out == "" and len(lines) == 1 and expect in lines[0], cap.err
    assert lines[0].startswith("biped"), lines[0]


def test_bad_option_in_a_fresh_process(tmp_path):
    r = subprocess.run([sys.executable, "-m", "analysis.cli", "view", "--port", "x"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert r.returncode == 2 and r.stdout == "" and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "--port" in r.stderr


def test_a_port_in_use_is_one_line(capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert biped_main(["view", "--port", str(port)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--port: {port} is in use" in err[0], err


def test_without_the_extra_it_says_how_to_install(monkeypatch, capsys):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "viser" else real(name, *a))
    assert biped_main(["view"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'pip install "biped-casadi[view]"' in err[0], err


def test_settings_name_what_is_wrong(gait):
    """ViewSettings took a path for the gait, any controller, an M1 of any shape and a
    rejoin past the section; they failed later, inside the explorer."""
    with pytest.raises(TypeError, match="^gait: a gait is needed"):
        ViewSettings("gait.json")
    with pytest.raises(ValueError, match="^controller must be 'tv' or 'vc', got 'x'$"):
        ViewSettings(gait, controller="x")
    for bad in (np.zeros((4, 1)), [1.0, 2.0, 3.0], [np.nan, 0, 0, 0]):
        with pytest.raises(ValueError, match="^M1 must"):
            ViewSettings(gait, M1=bad)
    with pytest.raises(ValueError, match="^rejoin must be in"):
        ViewSettings(gait, rejoin=2.0)
    with pytest.raises(ValueError, match="^options must be a SimulationOptions, got dict$"):
        ViewSettings(gait, options={"steps": 3})
    with pytest.raises(ValueError, match="^perturbation must be a Perturbation or None"):
        ViewSettings(gait, perturbation=(0.01, 0.1))
    assert ViewSettings(gait, M1=np.array(START)).M1 == START
