"""Real recordings in from ROS: bags + URDF -> the interchange format, and
corrected ground wrenches back out as a bag.

* :func:`ingest` / :func:`write_ingested`: map (:mod:`.mapfile`; an arm's ``[arm]`` map: :mod:`.arm`) -> dataset;
* :func:`robot_from_urdf`: nominal transducer poses from a URDF (:mod:`.urdf`);
* :func:`write_ground_wrench_bag`: one ``WrenchStamped`` topic per foot (:mod:`.bagio`).

Bags are read chunk by chunk and decoded with numpy (:mod:`.rawscan`,
:mod:`.wire`): ~1 million messages in a few seconds. :mod:`.simbag` writes
bags of any interchange dataset (tests, ``python -m ftcal_nlp.ros.bench``).
"""

from .bagio import BagError, ground_wrench_bag_from_frame, read_wrench_topics, write_ground_wrench_bag
from .arm import ArmMap
from .ingest import IngestCounts, IngestResult, ingest, read_any_map, write_ingested
from .mapfile import IngestMap, read_map
from .urdf import fixed_pose, robot_from_urdf, urdf_text

__all__ = [
    "ArmMap",
    "BagError",
    "IngestCounts",
    "IngestMap",
    "IngestResult",
    "fixed_pose",
    "ground_wrench_bag_from_frame",
    "ingest",
    "read_any_map",
    "read_map",
    "read_wrench_topics",
    "robot_from_urdf",
    "urdf_text",
    "write_ground_wrench_bag",
    "write_ingested",
]
