"""``python -m camplace`` runs the command line."""

import sys

from camplace.cli import main

sys.exit(main())
