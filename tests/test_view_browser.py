"""``biped view`` in a real browser (issue 48): the command is started as a user starts it,
the page is loaded in headless Chromium (Debian's package, driven by playwright) with
every request outside the server refused, the robot's legs are found on screen by their
colours, three designs are typed into the number boxes M1[1]..M1[4], and the page's
max|lambda| and walk are compared with ``biped eig`` and ``biped simulate`` for the same
design.  The last screenshot (the robot mid-step with the panel) is the how-to's picture,
docs/_static/view.png.  Ctrl-C then stops the server with exit code 0.

Needs the extra ``view`` (viser, playwright) and a Chromium; skipped without them, except
where $BIPED_REQUIRE_BROWSER is set (CI), where their absence fails the test.
"""
from __future__ import annotations

import colorsys
import importlib.util
import io
import json
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from analysis.cli import main as biped_main
from analysis.reporting.plots.images import role_colours

ROOT = Path(__file__).resolve().parents[1]
SHOT = ROOT / "docs" / "_static" / "view.png"
START = (-10.0, 7.5, 10.0, -5.0)
#: typed into the number boxes, in this order: a walk that slips, one that exceeds the
#: torque limit, and the start again (a walk that converges), all inside the sliders'
#: reach around the start
DESIGNS = [(-9.5, 7.5, 10.0, -5.0), (-11.0, 7.5, 10.0, -5.0), START]
CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run", "--disable-quic"]
SLOW_PAGE = 120_000            # ms: software WebGL on a loaded 2-core machine


def _requirements():
    """Chromium's path, or the reason the test cannot run."""
    missing = [m for m in ("viser", "playwright") if importlib.util.find_spec(m) is None]
    chromium = os.environ.get("BIPED_CHROMIUM") or shutil.which("chromium") \
        or "/usr/bin/chromium"
    if not Path(chromium).is_file():
        missing.append(f"a Chromium ({chromium})")
    if not missing:
        return chromium, None
    return None, f"needs {', '.join(missing)} (pip install '.[view]'; apt-get install chromium)"


def _lines(stream, q):
    for line in iter(stream.readline, ""):
        q.put(line)
    q.put(None)


def _start_view(args, timeout=300.0):
    """`biped view ARGS` as a process; (process, url, seconds to the ready line, lines)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "analysis.cli", "view", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=ROOT, env=dict(os.environ, MPLBACKEND="Agg"))
    out: queue.Queue = queue.Queue()
    threading.Thread(target=_lines, args=(proc.stdout, out), daemon=True).start()
    try:
        line = out.get(timeout=timeout)
    except queue.Empty:
        proc.kill()
        pytest.fail(f"biped view printed nothing within {timeout} s")
    if line is None:
        proc.wait(timeout=30)
        pytest.fail(f"biped view exited with {proc.returncode}: {proc.stderr.read()}")
    m = re.fullmatch(r"view: (http://127\.0\.0\.1:\d+)\n", line)
    assert m, line
    return proc, m.group(1), time.perf_counter() - t0, out


def _row(page, label: str):
    """The row of the control labelled exactly ``label``."""
    return page.locator(f"xpath=//label[normalize-space(text())='{label}']"
                        "/ancestor::*[.//input or .//textarea][1]")


def _text(page, label: str) -> str:
    return _row(page, label).locator("textarea").input_value()


def _wait_text(page, label: str, ok, what: str, timeout: float = 120.0) -> str:
    end = time.monotonic() + timeout
    while True:
        value = _text(page, label)
        if ok(value):
            return value
        if time.monotonic() > end:
            pytest.fail(f"{label!r} never showed {what}; last: {value!r}")
        time.sleep(0.1)


def _type(page, label: str, value: float):
    box = _row(page, label).locator("input.mantine-NumberInput-input")
    box.fill(repr(value))
    box.press("Tab")                       # commit (the box clamps on blur)


def _leg_pixels(png: bytes, right: int) -> dict:
    """Pixels left of x = ``right`` with the hue of the stance or the swing leg
    (saturated, not dark): the legs are lit, so their shades vary, not their hue."""
    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))[:, :right].reshape(-1, 3)
    colours, count = np.unique(rgb, axis=0, return_counts=True)
    hsv = np.array([colorsys.rgb_to_hsv(*(c / 255)) for c in colours])
    out = {}
    for role in ("stance", "swing"):
        h = colorsys.rgb_to_hsv(*(np.array(role_colours()[role]) / 255))[0]
        dh = np.abs(hsv[:, 0] - h)
        like = (np.minimum(dh, 1 - dh) < 0.03) & (hsv[:, 1] > 0.45) & (hsv[:, 2] > 0.25)
        out[role] = int(count[like].sum())
    return out


def _eig_lines(M1, capsys) -> dict:
    assert biped_main(["eig", "--m1", *map(repr, M1)]) == 0
    out = capsys.readouterr().out
    return dict(line.split(" = ", 1) if line.startswith("max|lambda|") else
                line.split(": ", 1) for line in out.splitlines()
                if line.startswith(("max|lambda| =", "eigenvalues:")))


def _simulate(args, capsys) -> dict:
    rc = biped_main(["simulate", *args, "--json"])
    sim = json.loads(capsys.readouterr().out)
    assert rc == (0 if sim["status"] == "ok" else 1)      # a stopped walk exits 1
    return sim


@pytest.mark.slow
def test_view_in_a_browser(gait, capsys):
    chromium, reason = _requirements()
    if reason:
        if os.environ.get("BIPED_REQUIRE_BROWSER"):
            pytest.fail(reason)
        pytest.skip(reason)
    from playwright.sync_api import sync_playwright
    from analysis.stability import poincare_eigenvalues

    t_test = time.perf_counter()
    proc, url, ready, out = _start_view(["--m1", *map(repr, START)])
    outside: list = []
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page(viewport={"width": 1280, "height": 720})
                page.set_default_timeout(SLOW_PAGE)
                page.route("**/*", lambda route: (route.continue_()
                           if route.request.url.startswith(url) else
                           (outside.append(route.request.url), route.abort())))
                page.goto(url)
                page.get_by_role("button", name="walk this M1").wait_for()
                start = f"M1 = {list(START)}"
                walks = [_wait_text(page, "walk", lambda v: start in v, "the first walk")
                         .splitlines()[0]]
                for M1 in DESIGNS:
                    walks.append(_check_design(page, M1, gait, capsys, poincare_eigenvalues))
                _screenshot(page)
                readout = _text(page, "max|lambda|")         # nothing broke meanwhile
                assert readout.endswith(f"M1 = {list(START)}") and "error" not in readout
            finally:
                browser.close()
        assert not outside, f"the page asked for {outside}"
        assert all(a != b for a, b in zip(walks, walks[1:])), walks
        assert len({w.split(":")[0] for w in walks}) >= 2, walks     # outcomes differ
    finally:
        proc.send_signal(signal.SIGINT)              # Ctrl-C
        try:
            rc = proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise
    rest = []
    while (line := out.get(timeout=10)) is not None:
        rest.append(line)
    err = proc.stderr.read()
    assert rc == 0, err
    assert rest == [] and "Traceback" not in err and "error" not in err, (rest, err)
    print(f"\nbiped view: ready in {ready:.2f} s (cold or warm as the cache is); "
          f"whole test {time.perf_counter() - t_test:.1f} s")


def _check_design(page, M1, gait, capsys, poincare_eigenvalues) -> str:
    """Type M1 into the number boxes; the readout must equal `biped eig`, the walk
    `biped simulate`; returns the walk's first line."""
    for j, v in enumerate(M1):
        _type(page, f"M1[{j + 1}]", v)
    shown = f"M1 = {list(M1)}"
    readout = _wait_text(page, "max|lambda|", lambda v: shown in v, shown).splitlines()
    cli = _eig_lines(M1, capsys)
    value, status = readout[0].split("   status: ")
    assert value == cli["max|lambda|"], (readout, cli)
    assert readout[1] == f"eigenvalues: {cli['eigenvalues']}", (readout, cli)
    digits = re.sub(r"^[-0.]*|e.*$|\.", "", value)
    assert len(digits) >= 6, value                       # at least six significant digits
    r = poincare_eigenvalues(gait, M1)
    assert status == r.status
    assert abs(float(value) - r.max_abs) <= 0.5 * 10.0 ** (np.floor(np.log10(r.max_abs)) - 7)

    page.get_by_role("button", name="walk this M1").click()
    walk = _wait_text(page, "walk", lambda v: shown in v and not v.startswith("walking"),
                      f"the walk of {shown}").splitlines()
    args = ["--controller", "tv", "--m1", *map(repr, M1), "--perturb", "0.001", "0.01",
            "--steps", "10"]
    assert _text(page, "replay") == "biped simulate " + " ".join(args)
    sim = _simulate(args, capsys)
    word, rest = walk[0].split(": ", 1)
    assert word == sim["status"], (walk, sim["status"], sim["message"])
    if sim["status"] == "ok":
        assert rest.startswith(f"{sim['n_steps']} of {sim['n_steps']} steps valid"), walk
    else:
        assert rest == sim["message"], (walk, sim["message"])
        assert int(re.match(r"step (\d+):", rest).group(1)) == sim["fail_step"] + 1  # 1-based
    return walk[0]


def _screenshot(page):
    """Pause mid-step, close the software-rendering notice, check the legs' colours and
    keep the picture for the how-to."""
    page.get_by_role("button", name="pause").click()
    page.get_by_role("button", name="play").wait_for()      # the clock has stopped
    time.sleep(0.5)                               # and its last tick has arrived
    box = _row(page, "time [s]").locator("input.mantine-NumberInput-input")
    box.fill("2.41")                              # the middle of the fourth step
    box.press("Tab")
    close = page.locator(".mantine-Notification-closeButton")
    for i in range(close.count()):
        close.nth(i).click()
    panel_left = int(page.get_by_role("button", name="walk this M1").bounding_box()["x"]) - 30
    time.sleep(2.0)                               # a few frames of software WebGL
    assert box.input_value() == "2.41"
    png = page.screenshot()
    legs = _leg_pixels(png, panel_left)
    assert legs["stance"] > 300 and legs["swing"] > 300, legs
    SHOT.parent.mkdir(parents=True, exist_ok=True)
    SHOT.write_bytes(png)
