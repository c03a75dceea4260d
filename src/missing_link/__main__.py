"""``python -m missing_link``: the command line (:mod:`missing_link.cli`)."""

import sys

from .cli import main

sys.exit(main())
