"""The ``biped`` command's entry point: loading the command line takes a second or two,
and a Ctrl-C meanwhile ends the command as one later would (one line, exit code 130),
not with a traceback of the imports."""
import sys

__all__ = ["main"]


def main() -> int:
    """Load and run :func:`analysis.cli.main` with the process's arguments.

    Returns
    -------
    int
        Its exit code; 130 when interrupted while loading.
    """
    try:
        from analysis.cli import main as run
    except (KeyboardInterrupt, ImportError) as e:
        if not _interrupted(e):
            raise
        command = next((a for a in sys.argv[1:] if not a.startswith("-")), None)
        print(f"biped {command}: interrupted" if command else "biped: interrupted",
              file=sys.stderr)
        return 130
    return run()


def _interrupted(e: BaseException) -> bool:
    """Whether ``e`` is a Ctrl-C, or an error an extension module's initialisation made
    of one (``ImportError: initialization failed``, caused by the KeyboardInterrupt)."""
    while e is not None:
        if isinstance(e, KeyboardInterrupt):
            return True
        e = e.__cause__ or e.__context__
    return False
