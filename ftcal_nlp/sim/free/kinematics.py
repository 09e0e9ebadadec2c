"""The URDF kinematics of the simulator live in :mod:`ftcal_nlp.kinematics` (shared with the estimator); re-exported here."""

from ...kinematics import MOVABLE, Body, Joint, KinematicTree, joint_transform, load_tree

__all__ = ["MOVABLE", "Body", "Joint", "KinematicTree", "joint_transform", "load_tree"]
