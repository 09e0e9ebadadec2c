"""``python -m ftcal_nlp COMMAND ...``: the one command line (:mod:`ftcal_nlp.cli`)."""

import sys

from .cli import main

sys.exit(main())
