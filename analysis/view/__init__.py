"""``biped view``: explore a design in the browser.

A viser server (the optional extra ``view``) shows the robot walking in 3-D and the
controls of the design: move M1 and see max|lambda| at once, walk it, replay the walk
with ``biped simulate``.  :mod:`~analysis.view.session` computes (no page),
:mod:`~analysis.view.space` chooses the sliders' start and reach,
:mod:`~analysis.view.poses` turns a run into 3-D poses, :mod:`~analysis.view.scene`
draws them and :mod:`~analysis.view.app` is the page.  viser is imported only when a
page is served.
"""
from .app import ViewApp
from .poses import DEPTH, WalkPoses, segment_frames, walk_poses
from .session import VIEW_PERTURBATION, Explorer, ViewSettings, Walk
from .space import SliderSpace, axis_ranges, slider_space

__all__ = ["ViewSettings", "Explorer", "Walk", "VIEW_PERTURBATION", "SliderSpace",
           "slider_space", "axis_ranges", "WalkPoses", "walk_poses", "segment_frames",
           "DEPTH", "ViewApp", "serve"]


def serve(settings: ViewSettings, host: str = "127.0.0.1", port: int = 0):
    """Start a view: compute the start, then serve the page until ``stop()``.

    Parameters
    ----------
    settings : ViewSettings
        What to show.
    host : str
        Address to listen on.
    port : int
        Port (0: a free one).

    Returns
    -------
    ViewApp
        The running view (``.url``, ``.stop()``).
    """
    return ViewApp(Explorer(settings), host, port)
