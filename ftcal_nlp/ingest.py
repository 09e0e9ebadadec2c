"""``python -m ftcal_nlp.ingest MAP.toml -o DATASET_DIR``: ROS bags -> interchange dataset.

A thin entry point; the work is in :mod:`ftcal_nlp.ros` (map, bag reading,
one clock, URDF). Needs the ``ros`` extra (``rosbags``, ``yourdfpy``).
"""

from __future__ import annotations

import sys

from .ros.cli import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())
