"""``python -m camplace`` runs the command line."""

import sys

from camplace.cli import console

sys.exit(console())
