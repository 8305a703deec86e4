"""``python -m analysis.cli`` runs the ``biped`` command line, as ``biped`` does
(:func:`biped_cli.main`: a Ctrl-C while it loads is one line and exit code 130)."""
import sys

from biped_cli import main

sys.exit(main())
