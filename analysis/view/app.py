"""The page of ``biped view``: a viser server with the robot's scene and its controls.

The controls keep fixed labels (the browser test finds them by these): a ``controller``
choice (tv / vc); sliders with number boxes ``M1[1]`` .. ``M1[nu]``; read-only texts
``max|lambda|`` (updated as soon as M1 changes), ``walk`` (the outcome and the design of
the walk on screen) and ``replay`` (the ``biped simulate`` command of that walk); the
buttons ``walk this M1`` and ``centre the sliders here``; the animation's ``time [s]``
slider, a play / pause button and a ``follow`` checkbox (the view keeps the hip at its
centre: the world shifts under the camera); the section basin of the walked design when the cache keeps one.

Threads: viser runs the callbacks in its own pool; the readout is computed under a lock
from the sliders' current values, so the last change wins; walks run in one worker
thread, the latest request only; the animation clock ticks in another.
"""
from __future__ import annotations

import contextlib
import io
import sys
import threading
import time

import numpy as np

from ..reporting.plots.images import basin_image
from .scene import RobotScene
from .session import Explorer, Walk
from .space import axis_ranges

__all__ = ["ViewApp", "M1_STEP", "FPS"]

#: step of the M1 sliders (their number boxes take two decimals)
M1_STEP = 0.01
#: frames per second of the animation clock
FPS = 30
TIME_STEP = 0.01
NO_BASIN = ("No section basin of this design in the cache: `biped reproduce` keeps the "
            "basins of its designs.")


class ViewApp:
    """A running view: the server, its scene and controls, and their threads.

    Parameters
    ----------
    explorer : Explorer
        The computations behind the page.
    host : str
        Address to listen on.
    port : int
        Port (0: a free one).
    """

    def __init__(self, explorer: Explorer, host: str = "127.0.0.1", port: int = 0):
        import viser                         # the optional extra 'view'
        self.explorer = explorer
        self.host = host
        self.controller = explorer.settings.controller
        with contextlib.redirect_stdout(io.StringIO()):          # viser's address table
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.scene = RobotScene(self.server)
        RobotScene.initial_camera(self.server, _hip_height(explorer))
        self.walk: Walk | None = None
        self._clock = 0.0
        self._playing = True
        self._stop = threading.Event()
        self._wake = threading.Condition()
        self._readout_lock = threading.Lock()
        self._basin_lock = threading.Lock()
        self._pending = None
        self._threads = [threading.Thread(target=self._walker, name="view-walks", daemon=True),
                         threading.Thread(target=self._player, name="view-clock", daemon=True)]
        self._gui()
        for t in self._threads:
            t.start()
        self.request_walk()                  # the first walk, while the readout is computed
        self._on_design()

    # ---------------------------------------------------------------- state
    @property
    def url(self) -> str:
        """Where the page is served."""
        return f"http://{self.host}:{self.server.get_port()}"

    @property
    def M1(self) -> tuple:
        """The design of the sliders."""
        return tuple(float(s.value) for s in self.sliders)

    def stop(self):
        """Stop the threads and the server."""
        self._stop.set()
        with self._wake:
            self._wake.notify_all()
        for t in self._threads:
            t.join(timeout=5)
        with contextlib.redirect_stdout(io.StringIO()):        # viser's goodbye line
            self.server.stop()

    # ---------------------------------------------------------------- controls
    def _gui(self):
        gui = self.server.gui
        gui.configure_theme(control_width="large", show_logo=False, show_share_button=False)
        ex, space = self.explorer, self.explorer.space
        gui.add_markdown(_header(ex))
        with gui.add_folder("design"):
            self.controller_box = gui.add_dropdown("controller", ("tv", "vc"),
                                                   initial_value=self.controller)
            self.sliders = [
                gui.add_slider(f"M1[{j + 1}]", min=lo, max=hi, step=M1_STEP,
                               initial_value=float(m),
                               hint=_slider_hint(j, space.stable[j]))
                for j, (m, (lo, hi)) in enumerate(zip(space.M1, space.ranges))]
            self.centre = gui.add_button("centre the sliders here",
                                         hint="new reaches around the current M1")
            self.eig_box = gui.add_text("max|lambda|", "", multiline=True, disabled=True)
            self.walk_button = gui.add_button("walk this M1")
            self.walk_box = gui.add_text("walk", "walking ...", multiline=True, disabled=True)
            self.replay_box = gui.add_text("replay", "", multiline=True, disabled=True)
        with gui.add_folder("animation"):
            self.time = gui.add_slider("time [s]", min=0.0, max=1.0, step=TIME_STEP,
                                       initial_value=0.0)
            self.play = gui.add_button("pause")
            self.follow = gui.add_checkbox("follow", True, hint="keep the hip in view")
        self.basin_folder = gui.add_folder("section basin")
        with self.basin_folder:
            self.basin_note = gui.add_markdown(NO_BASIN)
        self.basin_panel = None
        self._set_disabled()
        for s in self.sliders:
            s.on_update(self._guarded(self._on_design))
        self.controller_box.on_update(self._guarded(self._on_controller))
        self.centre.on_click(self._guarded(self._on_centre))
        self.walk_button.on_click(lambda _: self.request_walk())
        self.time.on_update(self._guarded(self._on_time, shown=False))
        self.play.on_click(self._guarded(self._on_play, shown=False))
        self.follow.on_update(self._guarded(self._on_time, shown=False))

    def _guarded(self, fn, shown: bool = True):
        """A callback whose failure is one line (in the readout box when ``shown``, on
        stderr otherwise), not a traceback."""
        def call(event=None):
            try:
                fn(event)
            except Exception as e:          # noqa: BLE001 - reported, the page goes on
                line = f"error: {type(e).__name__}: {e}"
                if shown:
                    self.eig_box.value = line
                else:
                    print(f"biped view: {line}", file=sys.stderr, flush=True)
        return call

    def _set_disabled(self):
        for s in self.sliders:
            s.disabled = self.controller == "vc"
        self.centre.disabled = self.controller == "vc"

    def _on_design(self, _=None):
        with self._readout_lock:
            try:
                text = self.explorer.readout(self.controller, self.M1)
            except ValueError as e:
                text = f"not computed: {e}"
            self.eig_box.value = text

    def _on_controller(self, _=None):
        self.controller = self.controller_box.value
        self._set_disabled()
        self._on_design()
        self.request_walk()

    def _on_centre(self, _=None):
        ranges, stable = axis_ranges(self.explorer.gait, self.M1, self.explorer.settings.rejoin)
        for j, (s, (lo, hi)) in enumerate(zip(self.sliders, ranges)):
            s.min, s.max = lo, hi
            s.hint = _slider_hint(j, stable[j])

    def _on_time(self, event=None):
        if event is not None and getattr(event, "client", None) is not None:
            self._clock = float(self.time.value)          # the user moved the clock
        self.scene.draw(float(self.time.value), follow=self.follow.value)

    def _on_play(self, _=None):
        self._playing = not self._playing
        self.play.label = "pause" if self._playing else "play"

    # ---------------------------------------------------------------- walks
    def request_walk(self):
        """Walk the current design (in the worker thread; the latest request wins)."""
        with self._wake:
            self._pending = (self.controller, None if self.controller == "vc" else self.M1)
            self._wake.notify_all()

    def _walker(self):
        while True:
            with self._wake:
                while self._pending is None and not self._stop.is_set():
                    self._wake.wait()
                if self._stop.is_set():
                    return
                controller, M1 = self._pending
                self._pending = None
            what = "virtual constraints" if M1 is None else f"M1 = {list(M1)}"
            self.walk_box.value = f"walking ... ({what})"
            try:
                self._show(self.explorer.walk(controller, M1))
            except Exception as e:          # noqa: BLE001 - shown on the page
                self.walk_box.value = f"not walked: {type(e).__name__}: {e}\n{what}"

    def _show(self, walk: Walk):
        if walk.poses is not None:
            self.walk = walk
            self.scene.show_walk(walk.poses)
            self._clock = 0.0
            self.time.max = max(round(walk.poses.duration, 2), TIME_STEP)
            self.time.value = 0.0
            self.scene.draw(0.0, follow=self.follow.value)
        self.walk_box.value = walk.text
        self.replay_box.value = (self.explorer.replay(walk.controller, walk.M1)
                                 if walk.result is not None else "")
        self._show_basin(walk)

    def _show_basin(self, walk: Walk):
        b = self.explorer.basin(walk.controller, walk.M1)
        with self._basin_lock:
            self._put_basin(b)

    def _put_basin(self, b):
        if self.basin_panel is not None:
            self.basin_panel.remove()
            self.basin_panel = None
        if b is None:
            self.basin_note.content = NO_BASIN
            return
        self.basin_note.content = f"{b.message} ({b.status})"
        with self.basin_folder:
            self.basin_panel = self.server.gui.add_image(basin_image(b), label="basin")

    def _player(self):
        last = time.perf_counter()
        while not self._stop.wait(1.0 / FPS):
            now = time.perf_counter()
            dt, last = now - last, now
            w = self.walk
            if not self._playing or w is None or w.poses is None:
                continue
            self._clock += dt
            if self._clock > w.poses.duration + 0.5:       # half a second at the end
                self._clock = 0.0
            if self._playing:                              # not paused meanwhile
                self.time.value = round(min(self._clock, w.poses.duration), 2)


def _hip_height(ex: Explorer) -> float:
    """The hip's height at the start of the gait, m."""
    m = ex.model
    return float(np.array(m.points(ex.gait.q(0.0)))[1, m.hip_index])


def _header(ex: Explorer) -> str:
    g, s = ex.gait, ex.settings
    return (f"**{ex.model.params.name}**, gait of period T = {g.T:.4g} s; walks of "
            f"{s.options.steps} steps. Sliders start at {ex.space.source}; the number "
            "boxes take values inside the sliders' reach.")


def _slider_hint(j: int, stable) -> str:
    if stable is None:
        return f"M1({j + 1}): the start is not stable along this axis"
    return (f"M1({j + 1}): stable from {stable[0]:.3g} to {stable[1]:.3g} with the other "
            "components at the start")
