"""On-disk cache of optimised running steps (:mod:`gait_opt.running`), as
:mod:`gait_opt.cache` keeps walking gaits.

A kept step is an entry of the toolkit's one cache
(:class:`biped_casadi.caching.ResultStore`) in the running-gait file format,
``<key>.running.json``, its key (:func:`biped_casadi.caching.task_key`) from the robot's
parameters, the complete options (lengths filled in for the robot) and the code of the
two lower layers (``code_version('gait')``: any change of ``biped_casadi`` or
``gait_opt`` that is more than a docstring, a comment or the layout gives a new key).
A kept file is used only if it loads (:meth:`RunningGait.load`), is the same robot's,
was made with the same options and converged; anything else is solved again and
the file replaced.  Only converged steps are kept.
"""
from __future__ import annotations

from pathlib import Path

from biped_casadi.caching import ResultStore, task_key

from .cache import _store

__all__ = ["running_cache_path", "cached_running"]

#: the kind written into a running-gait file, part of the key (the file format)
FORMAT = "running gait"


def running_cache_path(model, options, cache_dir=None) -> Path:
    """The cache file of the running step of a robot and options.

    Parameters
    ----------
    model : BipedModel
        The robot.
    options : RunningOptions
        The problem (its lengths are filled in for the robot first:
        :meth:`RunningOptions.for_model`).
    cache_dir : str or Path, optional
        The cache folder (default :func:`biped_casadi.cache_dir`).

    Returns
    -------
    Path
    """
    options = options.for_model(model)
    key = task_key("gait_opt.optimize_running", 1, "gait",
                   (model.params.to_dict(), options, FORMAT))
    return ResultStore(cache_dir).path(key, ".running.json")


def _kept(path: Path, model, options, load):
    """(the kept step at ``path``, or None and why not)."""
    if not path.exists():
        return None, "no kept step"
    try:
        g = load(path)
    except ValueError as e:
        return None, str(e)
    if g.robot != model.description.name:
        return None, f"made for {g.robot}"
    if g.options != options:
        return None, "made with other options"
    if not g.success:
        return None, "did not converge"
    return g, ""


def cached_running(model, options, cache_dir, progress, compute, load):
    """The running step of ``options`` from the on-disk cache, or ``compute()`` kept there.

    Parameters
    ----------
    model : BipedModel
        The robot.
    options : RunningOptions
        The problem, complete (:meth:`RunningOptions.for_model` applied).
    cache_dir : str or Path, optional
        Default :func:`biped_casadi.cache_dir`.
    progress : callable, optional
        Called with one line before a solve.
    compute : callable
        Solves the step; returns a :class:`RunningGait`.
    load : callable
        Reads a kept file (:meth:`RunningGait.load`: this module sits below the one
        that defines it).

    Returns
    -------
    RunningGait
        ``gait.solver_stats['cache']`` is 'hit' or says why it was solved (and, if it was
        not kept, why); ``solver_stats['cache_file']`` the file.
    """
    path = running_cache_path(model, options, cache_dir)
    g, reason = _kept(path, model, options, load)
    if g is not None:
        g.solver_stats.update(cache="hit", cache_file=str(path))
        return g
    if progress is not None:
        progress(f"optimising a running step of {model.description.name} at "
                 f"{options.speed:g} m/s (about 10 s; kept in {path.parent}) ...")
    g = compute()
    if not g.success:
        g.solver_stats["cache"] = f"computed ({reason}); not kept: it did not converge"
        return g
    return _store(g, path, reason)
