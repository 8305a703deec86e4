"""The ``biped`` command's entry point: loading the command line takes a second or two,
and a Ctrl-C meanwhile ends the command as one later would (one line, exit code 130),
not with a traceback of the imports."""
import atexit
import gc
import sys

__all__ = ["main", "interrupted"]


def main() -> int:
    """Load and run :func:`analysis.cli.main` with the process's arguments.

    Returns
    -------
    int
        Its exit code; 130 when interrupted while loading.
    """
    pressed, put_back = [], None
    try:
        try:
            put_back = _watch(pressed)
            from analysis.cli import main as run
        finally:
            if put_back is not None:
                put_back()
    except (KeyboardInterrupt, Exception) as e:
        if not (pressed or _interrupted(e)):
            raise
        rc = interrupted()
    else:                     # (a Ctrl-C a library dropped while it loaded: no command)
        rc = interrupted() if pressed else run()
    if rc == 130:
        _forget_the_interrupt()
    # no search of the whole heap for garbage cycles as Python exits (0.5-1.5 s of a warm
    # run, seconds under load, for memory that the ending process gives back anyway)
    atexit.register(gc.freeze)
    return rc


def interrupted(argv=None) -> int:
    """Say that the command of ``argv`` (default the process's arguments) was
    interrupted, in one line on stderr.

    Returns
    -------
    int
        130, the exit code of an interrupted command.
    """
    args = sys.argv[1:] if argv is None else argv
    command = next((a for a in args if not a.startswith("-")), None)
    print(f"biped {command}: interrupted" if command else "biped: interrupted",
          file=sys.stderr)
    return 130


def _forget_the_interrupt():
    """Clear CPython's record of a KeyboardInterrupt that left code run by ``exec`` or
    ``eval`` of a string (a dataclass's methods are made so while a module loads): with
    it, ``python -m`` ends the process by SIGINT once it exits (exit code -2 to its
    parent, not 130) even though the interruption was caught and said.  Each such code
    that completes clears the record (CPython's ``run_eval_code_obj``)."""
    exec("")


def _watch(pressed: list):
    """Python's Ctrl-C handler, noting each Ctrl-C in ``pressed``: a library may turn the
    KeyboardInterrupt into an error of its own that does not name it (NumPy's
    ``ImportError: PyCapsule_Import could not import module "datetime"``, a Ctrl-C while
    its extension loads).  Returns what puts Python's handler back (None: Ctrl-C is not
    Python's here, or this is not the main thread)."""
    import signal                    # (some ms: where a Ctrl-C is caught)

    def noted(signum, frame):
        pressed.append(signum)
        code = getattr(frame, "f_code", None)
        if code is not None and (code.co_filename, code.co_name) == (
                "<frozen importlib._bootstrap>", "cb"):
            return   # a module lock's weakref callback: Python would print the error and
        signal.default_int_handler(signum, frame)       # drop it (noted: said at the end)

    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return None
    try:
        signal.signal(signal.SIGINT, noted)
    except ValueError:                                  # not the main thread
        return None
    return lambda: signal.signal(signal.SIGINT, signal.default_int_handler)


def _interrupted(e: BaseException) -> bool:
    """Whether ``e`` is a Ctrl-C, or an error made of one: an extension module's
    initialisation (``ImportError: initialization failed``), a class's creation
    (``RuntimeError: Error calling __set_name__``), caused by the KeyboardInterrupt."""
    while e is not None:
        if isinstance(e, KeyboardInterrupt):
            return True
        e = e.__cause__ or e.__context__
    return False
