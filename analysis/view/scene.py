"""The 3-D scene of ``biped view`` in a viser server: the ground with a grid, the
footprints of a walk, and the robot as cylinders (links) and spheres (joints, feet,
head), the stance leg, the swing leg and the torso in the colours of every figure
(:func:`analysis.reporting.plots.images.role_colours`)."""
from __future__ import annotations

import threading

import numpy as np

from ..reporting.plots.images import role_colours
from .poses import DEPTH, WalkPoses, segment_frames

__all__ = ["RobotScene"]

GROUND = (214, 210, 200)
FOOTPRINT = (60, 60, 60)
#: margin of ground before the first and after the last footprint, m
MARGIN = 1.5


class RobotScene:
    """The robot and its ground in a viser scene; one walk at a time.

    Parameters
    ----------
    server : viser.ViserServer
        The server whose scene is drawn in.
    """

    def __init__(self, server):
        self.server = server
        self.scene = server.scene
        self.colours = role_colours()
        self.poses: WalkPoses | None = None
        self._frames: dict = {}
        self._links: dict = {}
        self._joints: dict = {}
        self._prints: list = []
        self.scene.set_up_direction("+z")
        self._world = self.scene.add_frame("/world", show_axes=False)
        self._lock = threading.RLock()     # a walk replaced while the clock draws

    def show_walk(self, poses: WalkPoses):
        """Draw the ground and footprints of a walk and make its robot current.

        Parameters
        ----------
        poses : WalkPoses
            The walk.
        """
        with self._lock:
            self._show(poses)

    def _show(self, poses: WalkPoses):
        scene = self.scene
        x = poses.footprints[:, 0]
        lo, hi = min(x.min(), poses.hip[:, 0].min()) - MARGIN, \
            max(x.max(), poses.hip[:, 0].max()) + MARGIN
        with self.server.atomic():
            scene.add_box("/world/ground", color=GROUND, dimensions=(hi - lo, 1.2, 0.02),
                          position=((lo + hi) / 2, 0.0, -0.0105), cast_shadow=False)
            scene.add_grid("/world/grid", width=hi - lo, height=1.2, plane="xy",
                           cell_size=0.1, section_size=0.5, position=((lo + hi) / 2, 0.0, 0.0105),
                           cell_color=(170, 165, 155), section_color=(120, 115, 105))
            for handle in self._prints:
                handle.remove()
            self._prints = [scene.add_box(f"/world/footprints/{i}", color=FOOTPRINT,
                                          dimensions=(0.12, 0.05, 0.004),
                                          position=p + (0, 0, 0.002))
                            for i, p in enumerate(poses.footprints)]
            self._frames = {name: segment_frames(s.a, s.b)
                            for name, s in poses.segments.items()}
            for name, s in poses.segments.items():
                length = float(np.median(self._frames[name][2]))
                self._links[name] = scene.add_cylinder(
                    f"/world/robot/{name}", radius=s.radius, height=length,
                    color=self.colours[s.role], radial_segments=20)
            for name, (role, radius, _) in poses.joints.items():
                self._joints[name] = scene.add_icosphere(
                    f"/world/robot/joint_{name}", radius=radius, color=self.colours[role],
                    subdivisions=2)
        self.poses = poses

    def draw(self, time: float, follow: bool = True) -> int:
        """Put the robot of the current walk at ``time``.

        Parameters
        ----------
        time : float
            Seconds since the start of the walk (the instant at or before it is drawn).
        follow : bool
            Keep the hip under the camera: the world is shifted along x (the camera's
            angle and distance stay as the user left them); else the world is not moved.

        Returns
        -------
        int
            The index of the instant drawn (-1: no walk yet).
        """
        with self._lock:
            poses = self.poses
            if poses is None:
                return -1
            k = poses.index(time)
            with self.server.atomic():
                for name, handle in self._links.items():
                    pos, wxyz, _ = self._frames[name]
                    handle.position = pos[k]
                    handle.wxyz = wxyz[k]
                for name, handle in self._joints.items():
                    handle.position = poses.joints[name][2][k]
                x = float(poses.hip[k, 0]) if follow else 0.0
                self._world.position = (-x, 0.0, 0.0)
            return k

    @staticmethod
    def initial_camera(server, hip_height: float):
        """Point new clients' cameras at the robot from the side (-y), a little above
        and behind.

        Parameters
        ----------
        server : viser.ViserServer
            The server.
        hip_height : float
            Height of the hip, m.
        """
        z = float(hip_height)
        server.initial_camera.look_at = (0.35, 0.0, 0.65 * z)
        server.initial_camera.position = (-0.45, -2.0 - DEPTH, 1.15 * z)
