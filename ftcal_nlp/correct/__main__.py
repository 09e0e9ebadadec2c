"""``python -m ftcal_nlp.correct``."""

from . import main

raise SystemExit(main())
