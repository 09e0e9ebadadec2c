"""The effect library: one unit per effect, in one folder, in a registry that is a plain dict.

An effect is one module here, named by its canonical name (``OUTPUT_FORMAT.md``), that
declares together (:class:`~.unit.Effect`): its kind (sensor / body), its simulator
injector (an :class:`~.injection.EffectInjector`), its model faces and their variants
(the diagnosis' augmentations of the calibration model, built from :mod:`.faces`), its
correction for ``correct`` (:meth:`Effect.correct`) and its off-face validation shapes.
:data:`EFFECTS` (``registry.py``) maps each name of the contract's list
``LIBRARY_EFFECTS`` to its unit; adding an effect touches its unit and that list only.

Modules:

* ``injection.py``: the simulator hook (:class:`InjectionContext`, :class:`Injector`,
  :class:`NoEffect`, ``apply_*``) and the injectors' bases (:class:`EffectInjector`,
  :class:`Magnitude`, :class:`OffFaceInjector`).
* ``faces.py``: the model faces' building blocks (:class:`PoseSym`, :class:`StandingData`,
  :func:`pose_symbols`, :class:`AugContext`, :class:`ParamBlock`, :class:`HangingLeg`,
  :class:`LinearFace`, :func:`legendre_time`, :func:`design_check`).
* ``unit.py``: :class:`Effect`, what a unit declares; ``correction.py``: the one effect correction
  ``correct`` calls for every load (a hexapod calibration's block through ``Effect.correct``, a sensor
  effect's standing face evaluated on samples by ``faces.correct_by_face``; a free load's members through
  ``free_correct`` and the units' hooks).
* ``free_faces.py``: the free-load face protocol (issue 23): :class:`FreeLoadContext`,
  :class:`FreeFace`, :func:`make_context`; units declare ``free_shapes``/``free_face``/``free_correct``.
* ``combined.py``: :class:`~.combined.Combined`, several units as one augmentation (the hexapod chain of
  effects, issue 23: standing corrections added, linear faces stacked, :func:`.faces.stack_faces`).
* ``registry.py``: ``LIBRARY_EFFECTS``, :data:`EFFECTS`, :func:`resolve_effects`,
  :func:`with_units` (a copy with a toy effect added), :func:`injector_classes`.
* the units: ``offset_drift``, ``gain_crosstalk``, ``casing_load``, ``mocap_bias``,
  ``chassis_flex``, ``tether_force``, ``hysteresis``, ``leg_inertia``, ``robot_mass``,
  ``sensor_nonlinearity``, ``moving_com``, ``clock_offset``, ``creep``, ``inertial_load``,
  ``joint_limit_contact``, ``temperature``; ``signals.py``: the time-series helpers their
  injectors and faces share (resampling with a delay, first-order lags); ``free_refine.py``: a free
  face's shape refined on the residual beside the free-load model's own columns.

Nothing here imports the diagnosis, the pipeline, ``correct`` or the simulator: they
import this package (the simulator registers :func:`injector_classes` under its
effect names; the diagnosis scores :data:`EFFECTS`; ``correction.py`` calls
:meth:`Effect.correct` and the free-load hooks).
"""

from .faces import AugContext, HangingLeg, LinearFace, ParamBlock, PoseSym, StandingData, design_check, pose_symbols
from .injection import (
    EXPECT_NONE,
    EXPECT_UNEXPLAINED,
    EffectInjector,
    InjectionContext,
    Injector,
    Magnitude,
    NoEffect,
    OffFaceInjector,
)
from .registry import (
    EFFECTS,
    LIBRARY_EFFECTS,
    applies_to,
    check_unit,
    injector_classes,
    resolve_effects,
    shape_classes,
    with_units,
)
from .unit import EFFECT_KINDS, Effect

__all__ = [
    "EFFECTS", "EXPECT_NONE", "EXPECT_UNEXPLAINED", "EFFECT_KINDS", "LIBRARY_EFFECTS",
    "AugContext", "Effect", "EffectInjector", "HangingLeg", "InjectionContext", "Injector", "LinearFace", "Magnitude",
    "NoEffect", "OffFaceInjector", "ParamBlock", "PoseSym", "StandingData", "applies_to",
    "check_unit", "design_check", "injector_classes", "pose_symbols", "resolve_effects", "shape_classes", "with_units",
]
