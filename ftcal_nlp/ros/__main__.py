"""``python -m ftcal_nlp.ros MAP.toml -o DATASET_DIR`` (same as ``python -m ftcal_nlp.ingest``)."""

import sys

from ..ingest import main

sys.exit(main())
