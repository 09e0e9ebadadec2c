"""Loads below a transducer as plug-ins, beside the error models (``DATA_FORMAT.md`` section 5).

``LOADS`` is a plain dict name -> class; :func:`resolve` takes a registered
name or ``"package.module:Class"`` / ``"path/file.py:Class"`` (as the error
models' :func:`ftcal_nlp.models.resolve`). Built in:

* ``leg_com_curve`` -- :class:`LegComCurve`, a hexapod leg's CoM curve over
  ``phi`` (delegates to the hanging calibration);
* ``rigid_payload`` -- :class:`RigidPayload`, a tool on a wrist: mass and
  first moment (oriented by the transducer's ``rotation``, or on an arm whose URDF
  leaves the tool out by the joints through the URDF: the transducer's ``link``);
* ``urdf_subtree`` -- :class:`UrdfSubtree`, the URDF links below a sensor,
  grouped by the joints that move them: mass and first moment per group.

The last two are :class:`LinearLoad`: linear in their parameters, served by
the one free-load estimator (:mod:`ftcal_nlp.estimate.freeload`). :func:`load_for`
builds the load of a transducer from the dataset (its ``load_kind``).
"""

from __future__ import annotations

from ..core.plugins import load_class
from .base import LinearLoad, se_of
from .leg_com_curve import LegComCurve
from .rigid_payload import RigidPayload
from .urdf_subtree import Group, UrdfSubtree, groups_below

LOADS: dict[str, type] = {"leg_com_curve": LegComCurve, "rigid_payload": RigidPayload, "urdf_subtree": UrdfSubtree}


def resolve(name: str) -> type:
    """A load class from a registered name or ``module:Class`` / ``file.py:Class``."""
    if name in LOADS:
        return LOADS[name]
    if ":" not in name:
        raise ValueError(f"unknown load {name!r}; known loads: {sorted(LOADS)} (or 'module:Class' / 'file.py:Class')")
    return load_class(name, "load")


def load_for(dataset, leg: str, name: str | None = None) -> LinearLoad:
    """The free load of transducer ``leg`` of ``dataset`` (``name``: a registered load or ``module:Class`` to use
    instead of the dataset's ``load_kind``; a class is built as ``cls(dataset, leg)`` when it is not built in)."""
    robot = dataset.robot
    kind = name or dataset.load_kind(leg)
    if kind == "rigid_payload":
        link = robot.transducers[leg].link
        if link is not None:   # an arm whose URDF leaves the tool out: oriented by the joints
            return RigidPayload(tree=robot.tree, ft_link=link)
        return RigidPayload(robot.transducers[leg].rotation)
    if kind == "urdf_subtree":
        return UrdfSubtree(robot.tree, robot.transducers[leg].link)
    if kind == "leg_com_curve":
        raise ValueError(f"transducer {leg}: a hexapod leg (column {leg}_phi) is calibrated by the hanging stage, not the free-load estimator")
    cls = resolve(kind)
    return cls(dataset, leg)


__all__ = ["LOADS", "resolve", "load_for", "LinearLoad", "LegComCurve", "RigidPayload", "UrdfSubtree", "Group", "groups_below", "se_of"]
