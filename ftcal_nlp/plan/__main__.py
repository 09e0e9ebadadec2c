"""``python -m ftcal_nlp.plan``: the plan command (:mod:`ftcal_nlp.plan.command`)."""

from .command import main

raise SystemExit(main())
