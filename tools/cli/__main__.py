"""``python -m tools.cli``: the command line, as the launcher starts the parts of a run."""

import sys

from tools.cli import main

sys.exit(main())
