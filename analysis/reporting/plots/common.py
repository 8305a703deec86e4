"""What every figure shares: the colours of the legs and the torso, a figure on its own
canvas, writing figures to files, the stick figure of a pose and the label of a run."""
from __future__ import annotations

import contextlib
from pathlib import Path

from matplotlib import rcParams
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from biped_casadi.files import atomic_path

__all__ = ["COLOUR_NAMES", "STANCE", "SWING", "TORSO", "save_figure", "save_figures",
           "run_label"]

#: colours of the stance leg, the swing leg and the torso in every stick figure
STANCE, SWING, TORSO = "tab:blue", "tab:red", "0.25"
#: how captions name them (one place, so a caption never names a colour not drawn)
COLOUR_NAMES = {STANCE: "blue", SWING: "red", TORSO: "dark grey"}


def _figure(**kw) -> Figure:
    fig = Figure(**kw)
    FigureCanvasAgg(fig)
    return fig


@contextlib.contextmanager
def tight_box(fig: Figure, dpi: float):
    """The figure's tight bounding box, found once for all its files.

    ``savefig(..., bbox_inches="tight")`` lays out and measures the whole figure again
    for every file it writes (and draws it twice); this measures it once, at ``dpi`` with
    the raster renderer, as ``savefig`` does for a PNG, and holds the figure's layout
    (no layout engine) while the files are written with ``bbox_inches=box``.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    dpi : float
        The resolution the box is measured at (the PNG's).

    Yields
    ------
    matplotlib.transforms.Bbox or str
        The box in inches, padded by ``rcParams['savefig.pad_inches']`` ('tight' for a
        figure whose canvas has no Agg renderer: ``savefig`` measures it per file).
    """
    if not (hasattr(fig.canvas, "get_renderer") and hasattr(fig, "_layout_engine")):
        yield "tight"          # not drawn by Agg, or a matplotlib without the attribute
        return
    engine, old_dpi = fig.get_layout_engine(), fig.dpi
    fig.dpi = dpi
    try:
        renderer = fig.canvas.get_renderer()
        with renderer._draw_disabled():                   # the layout, nothing painted
            fig.draw(renderer)
        box = fig.get_tightbbox(renderer).padded(rcParams["savefig.pad_inches"])
    finally:
        fig.dpi = old_dpi
    # no layout engine while the files are written, not even the placeholder that
    # tight_layout() leaves: with one, savefig lays the figure out again for each file
    fig._layout_engine = None
    try:
        yield box
    finally:
        fig._layout_engine = engine


def save_figure(fig: Figure, path, formats=("png",), dpi: int = 150) -> list[str]:
    """Write ``fig`` to ``path`` with each suffix of ``formats``.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : str or Path
        File name; its suffix (if .png or .pdf) is replaced by each format.
    formats : sequence of str
        'png', 'pdf', ...
    dpi : int

    Returns
    -------
    list of str
        The files written.  Each is written through a temporary file: a failure leaves
        no partial figure and does not damage an earlier one.
    """
    base = Path(path)
    if base.suffix.lower() in (".png", ".pdf", ".svg"):
        base = base.with_suffix("")
    out = []
    with tight_box(fig, dpi) as box:
        for ext in formats:
            p = base.with_name(f"{base.name}.{ext}")
            with atomic_path(p) as tmp:
                fig.savefig(tmp, dpi=dpi, bbox_inches=box, format=ext)
            out.append(str(p))
    return out


def save_figures(figures: dict, folder, formats=("png",), dpi: int = 150) -> list[str]:
    """Write several figures into ``folder`` (created if needed), all or none.

    Parameters
    ----------
    figures : dict
        File name (without suffix) -> Figure.
    folder : str or Path
    formats, dpi
        As :func:`save_figure`.

    Returns
    -------
    list of str
        The files written.  When one fails, those already written by this call are
        removed (and the folder too, if this call created it) before the error propagates.
    """
    folder = Path(folder)
    created = not folder.exists()
    folder.mkdir(parents=True, exist_ok=True)
    written: list[str] = []
    try:
        for name, fig in figures.items():
            written += save_figure(fig, folder / name, formats, dpi)
    except BaseException:
        for f in written:
            Path(f).unlink(missing_ok=True)
        if created:
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    return written


def _legend_below(fig: Figure, axes, fontsize: float = 8, ncol: int = 1, x: float = 0.5):
    """One legend for ``axes`` under the figure, where it cannot cover a curve.

    Call it after the layout (``tight_layout``): the legend hangs below the figure's
    bottom edge, and the saved file's tight box (:func:`save_figure`) takes it in.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    axes : Axes or sequence of Axes
        Their labelled artists, in order, each label once.
    fontsize : float
    ncol : int
    x : float
        The legend's centre, in figure coordinates (0.5: under the middle).

    Returns
    -------
    matplotlib.legend.Legend or None
        None when nothing is labelled.
    """
    handles, labels = [], []
    for ax in (axes if isinstance(axes, (list, tuple)) else [axes]):
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    if not handles:
        return None
    return fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(x, 0.0),
                      fontsize=fontsize, ncol=ncol, frameon=False)


# ---------------------------------------------------------- stick figures
def _stick(ax, model, P, alpha=1.0, lw=2.0):
    """One stick figure from the model's points (``model.points``: stance foot, stance
    joints, hip, torso top, swing joints, swing foot), drawn along its chains."""
    st, to, sw = (list(c) for c in (model.stance_chain, model.torso_chain, model.swing_chain))
    ax.plot(P[0, st], P[1, st], "-", color=STANCE, lw=lw, alpha=alpha)
    ax.plot(P[0, to], P[1, to], "-", color=TORSO, lw=lw + 1, alpha=alpha)
    ax.plot(P[0, sw], P[1, sw], "-", color=SWING, lw=lw, alpha=alpha)


def _legs_legend(ax, extra=(), outside: bool = False):
    """The legend of the stick figures' colours: in the axes' upper left corner, or
    (``outside``) beside the axes, clear of the poses."""
    handles = [Line2D([], [], color=STANCE, lw=2, label="stance leg"),
               Line2D([], [], color=SWING, lw=2, label="swing leg"),
               Line2D([], [], color=TORSO, lw=3, label="torso"), *extra]
    if outside:
        ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8)
    else:
        ax.legend(handles=handles, loc="upper left", fontsize=8)


# ------------------------------------------------------------------ runs
def run_label(res) -> str:
    """A legend label for a simulation result.

    Parameters
    ----------
    res : SimulationResult
        A closed-loop run.

    Returns
    -------
    str
        The controller (and M1 for the time-varying one).
    """
    c = res.controller
    if c.get("controller") == "tv":
        return "time-varying, M1 = [" + ", ".join(f"{v:.4g}" for v in c["M1"]) + "]"
    return "virtual constraints"
