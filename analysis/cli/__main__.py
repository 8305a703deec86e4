"""``python -m analysis.cli`` runs the ``biped`` command line."""
import sys

from analysis.cli import main

sys.exit(main())
