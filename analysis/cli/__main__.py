"""``python -m analysis.cli`` runs the ``biped`` command line, as ``biped`` does
(:func:`biped_cli.main`: a Ctrl-C while it loads is one line and exit code 130)."""
import sys

try:
    from biped_cli import main
except KeyboardInterrupt:              # while Python looked for it (an editable install's
    from biped_cli import interrupted  # import finder: some ms)
    sys.exit(interrupted())
sys.exit(main())
