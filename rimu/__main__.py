"""``python -m rimu`` runs the command-line interface."""

import sys

from rimu.cli import main

sys.exit(main())
