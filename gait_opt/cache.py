"""On-disk cache of optimised gaits, so the default gait is solved once per machine.

A cached gait is an entry of :data:`GAITS` (a :class:`biped_casadi.caching.DiskCache`):
``<cache_dir>/gaits/gaits-<key>.json`` in the ordinary gait file format, ``key`` from the
robot parameters, the gait options, the file format and the optimiser's version (bumped
whenever its result for the same options changes).  A cached file
is used only if it loads cleanly (:meth:`Gait.load`: checksum, format version, schema,
robot parameters, a periodic orbit to :data:`gait_opt.gait.ORBIT_TOL`) and was made with
the same options; anything else is recomputed and overwritten, never trusted.
"""
from __future__ import annotations

from pathlib import Path

from biped_casadi import rabbit
from biped_casadi.caching import DiskCache, claimed

from .gait import FORMAT_VERSION, Gait, GaitFileError
from .optimize import optimize_gait
from .options import GaitOptions

__all__ = ["default_gait", "cache_path", "GAITS"]

#: the optimised gaits kept between sessions (version: the optimiser's output for given
#: options)
GAITS = DiskCache("gaits", version=1)


def cache_path(model=None, options: GaitOptions | None = None, cache_dir_=None) -> Path:
    """The cache file of the gait of a robot and options.

    Parameters
    ----------
    model : BipedModel, optional
        Default RABBIT.
    options : GaitOptions, optional
        Default: SPEC section 2 (the robot's torque limit filled in).
    cache_dir_ : str or Path, optional
        The cache folder (default :func:`biped_casadi.cache_dir`).

    Returns
    -------
    Path
    """
    model = model or rabbit()
    options = (options or GaitOptions()).for_model(model)
    return GAITS.path(dict(robot=model.params.to_dict(), options=options.to_dict(),
                           format_version=FORMAT_VERSION), cache_dir_)


def _usable(path: Path, model, options: GaitOptions):
    """The cached gait, or None (with the reason) when it must be recomputed."""
    try:
        g = Gait.load(path, model=model)
    except GaitFileError as e:
        return None, str(e)
    if g.options != options:
        return None, "made with other options"
    return g, ""


def default_gait(model=None, options: GaitOptions | None = None, cache_dir=None,
                 progress=None, **overrides) -> Gait:
    """The optimal gait for ``options``, read from the on-disk cache or optimised once.

    The cache file is :func:`cache_path` (keyed by the robot, the options and the
    optimiser's version).  It is used only if it loads cleanly
    (:meth:`Gait.load`: checksum, schema, robot, a periodic orbit) and was made with the
    same options; otherwise the gait is optimised with :func:`optimize_gait` and stored.

    Parameters
    ----------
    model : BipedModel, optional
        Default RABBIT; any robot's model (the cache is keyed by its description).
    options : GaitOptions, optional
        Default: SPEC section 2.
    cache_dir : str or Path, optional
        Default: :func:`biped_casadi.cache_dir`.
    progress : callable, optional
        Called with one line of text before a gait is optimised (a few seconds).
    **overrides
        Replace option fields.

    Returns
    -------
    Gait
        ``gait.solver_stats['cache']`` says 'hit' or why it was (re)computed.
    """
    model = model or rabbit()
    options = options or GaitOptions()
    if not isinstance(options, GaitOptions):
        raise ValueError(f"options must be GaitOptions, got {type(options).__name__}")
    if overrides:
        options = options.replace(**overrides)
    options = options.for_model(model)
    path = cache_path(model, options, cache_dir)
    g, reason = _cached(path, model, options)
    if g is not None:
        return g
    # one process optimises it; another asking for it meanwhile waits and reads it
    with claimed(path):
        g, reason = _cached(path, model, options)
        if g is not None:
            return g
        if progress is not None:
            progress(f"optimising the reference gait of {model.params.name} (a few "
                     f"seconds, once; stored in {path.parent}) ...")
        g = optimize_gait(model, options)
        return _store(g, path, reason)


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
    note = f"computed ({reason})"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        g.save(path)
        g.solver_stats["cache_file"] = str(path)
    except OSError as e:          # a read-only cache is not fatal: the gait is still valid
        note += f"; not stored: {e}"
    g.solver_stats["cache"] = note
    return g
