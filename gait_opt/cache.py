"""On-disk cache of optimised gaits, so the default gait is solved once per machine.

A cached gait is an entry of the cache (:class:`biped_casadi.caching.ResultStore`) in the
ordinary gait file format, ``<key>.gait.json``, its key
(:func:`biped_casadi.caching.task_key`) from the robot, the gait options, the file format
and the code of the two lower layers (``code_version('gait')``).  A cached file
is used only if it loads cleanly (:meth:`Gait.load`: checksum, format version, schema,
robot parameters, a periodic orbit to :data:`gait_opt.gait.ORBIT_TOL`) and was made with
the same options; anything else is recomputed and overwritten, never trusted.
"""
from __future__ import annotations

from pathlib import Path

from biped_casadi import rabbit
from biped_casadi.caching import ResultStore, task_key

from .gait import FORMAT_VERSION, Gait, GaitFileError
from .options import GaitOptions

__all__ = ["cached_gait", "cache_path"]


def cache_path(model=None, options: GaitOptions | None = None, cache_dir_=None) -> Path:
    """The cache file of the gait of a robot and options.

    Parameters
    ----------
    model : BipedModel, optional
        Default RABBIT.
    options : GaitOptions, optional
        Default: docs: theory §2 (the robot's torque limit filled in).
    cache_dir_ : str or Path, optional
        The cache folder (default :func:`biped_casadi.cache_dir`).

    Returns
    -------
    Path
    """
    model = model or rabbit()
    options = (options or GaitOptions()).for_model(model)
    key = task_key("gait_opt.optimize_gait", 1, "gait", (model.params.to_dict(),
                                                        options.to_dict(), FORMAT_VERSION))
    return ResultStore(cache_dir_).path(key, ".gait.json")


def _usable(path: Path, model, options: GaitOptions):
    """The cached gait, or None (with the reason) when it must be recomputed."""
    try:
        g = Gait.load(path, model=model)
    except GaitFileError as e:
        return None, str(e)
    if g.options != options:
        return None, "made with other options"
    return g, ""


def cached_gait(model, options: GaitOptions, cache_dir, progress, compute) -> Gait:
    """The gait of ``options`` from the on-disk cache, or ``compute()`` stored there.

    The cache file is :func:`cache_path`; it is used only if it loads cleanly
    (:meth:`Gait.load`: checksum, schema, robot, a periodic orbit) and was made with the
    same options, otherwise the gait is computed again and the file replaced.

    Parameters
    ----------
    model : BipedModel
        The robot.
    options : GaitOptions
        The problem (complete: :meth:`GaitOptions.for_model` applied).
    cache_dir : str or Path, optional
        Default :func:`biped_casadi.cache_dir`.
    progress : callable, optional
        Called with one line before a solve.
    compute : callable
        Solves the gait.

    Returns
    -------
    Gait
        ``gait.solver_stats['cache']`` says 'hit' or why it was computed.
    """
    path = cache_path(model, options, cache_dir)
    g, reason = _cached(path, model, options)
    if g is not None:
        return g
    if progress is not None:
        progress(f"optimising the reference gait of {model.params.name} (a few seconds, "
                 f"once; stored in {path.parent}) ...")
    # two processes solving it at once compute the same gait; each file is written whole
    return _store(compute(), path, reason)


def _cached(path, model, options):
    """(the kept gait at ``path`` or None, why not)."""
    if not path.exists():
        return None, "no cached file"
    g, reason = _usable(path, model, options)
    if g is not None:
        g.solver_stats["cache"] = "hit"
        g.solver_stats["cache_file"] = str(path)
    return g, reason


def _store(g, path, reason):
    """Write a solved gait or running step to its cache file; its ``solver_stats`` say
    where, or why it could not be written (a read-only cache is not fatal)."""
    note = f"computed ({reason})"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        g.save(path)
        g.solver_stats["cache_file"] = str(path)
    except OSError as e:          # a read-only cache is not fatal: the gait is still valid
        note += f"; not stored: {e}"
    g.solver_stats["cache"] = note
    return g
