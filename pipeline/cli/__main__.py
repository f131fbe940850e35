"""``python -m pipeline.cli ...``: the same as ``jnr ...``."""

import sys

from pipeline.cli import main

sys.exit(main())
