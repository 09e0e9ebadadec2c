"""``python -m ftcal_nlp.export``."""

from . import main

raise SystemExit(main())
