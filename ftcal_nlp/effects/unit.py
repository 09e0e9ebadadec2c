"""What an effect is: one unit that declares every face of one canonical effect.

An effect unit (``ftcal_nlp/effects/<name>.py``, one per name of the contract's list
``registry.LIBRARY_EFFECTS``) is a subclass of :class:`Effect` with, together:

* ``name`` (canonical, ``OUTPUT_FORMAT.md``) and ``kind``: ``"sensor"`` (it acts on a
  transducer's readings: corrected per reading) or ``"body"`` (it acts outside the
  transducers: on the body, its weighed mass or its measured orientation);
* the simulator face: ``injector_cls`` (an :class:`~.injection.EffectInjector`; its
  ``magnitude`` is the unit's);
* the model faces (:mod:`.faces`): ``standing_params``/``standing`` (eq. (A)),
  ``hanging_features``, ``swing_features``, ``design_face`` (a common tilt of the fitted
  frames) and their flexibility, ``variants`` (attribution) and ``joint_variants``
  (the joint refit);
* the correction for ``correct``: :meth:`Effect.correct` (default: a sensor effect's
  standing face evaluated on the samples, :func:`.faces.correct_by_face`; a body
  effect changes no per-foot wrench);
* the free-load face (``free_faces.py``): ``free_shapes``, ``free_face``, ``free_correct``, ``free_explains``;
  and what its correction of a new recording needs (``correction.py``): ``follows_stream_clock``,
  ``free_reference``/``free_reference_keys`` (what the face takes from the whole calibration session),
  ``free_require`` (a signal the recording must carry), ``free_session_check`` (a warning where it extrapolates);
* the off-face validation shapes: ``shapes``, :class:`~.injection.OffFaceInjector`
  classes of the same effect with other shapes (what the validation sweep injects to
  test that the diagnosis is not tuned to the face's own formula).

The module's ``EFFECT`` (an instance, the default variant) is what the registry holds.
"""

from __future__ import annotations

import logging
from typing import ClassVar

import numpy as np

from .faces import AugContext, HangingLeg, LinearFace, ParamBlock, PoseSym, correct_by_face
from .injection import EffectInjector, Magnitude, NoEffect, OffFaceInjector

log = logging.getLogger(__name__)

EFFECT_KINDS = ("sensor", "body")


class Effect:
    """One effect: its name, kind, injector, model faces, correction and off-face shapes (module docstring).

    Subclasses set ``name``, ``kind``, ``description``, ``explains`` (the dependence
    localisation should find), ``injector_cls`` and ``shapes``, and override the faces
    they have; ``magnitude`` is ``injector_cls.magnitude`` unless set.
    """

    name: ClassVar[str] = ""
    kind: ClassVar[str] = "sensor"
    description: ClassVar[str] = ""
    explains: ClassVar[str | None] = None
    magnitude: ClassVar[Magnitude] = Magnitude("", (0.0, 0.0), 0.0)
    injector_cls: ClassVar[type] = NoEffect
    #: off-face validation shapes: OffFaceInjector classes whose ``expect`` is this effect
    shapes: ClassVar[tuple[type[OffFaceInjector], ...]] = ()
    #: the calibration settings under which the standing face is meaningful
    needs_report_balance: ClassVar[bool] = False
    #: the effect acts while hanging, so the hanging offsets absorbed part of it: the standing
    #: face gets a constant wrench in B (6 parameters) for the shifted offsets
    shifts_offsets: ClassVar[bool] = False
    #: its hanging face moves the offsets in the joint hanging fit (``diagnose/refit.py``) as they are, so the joint
    #: standing fit holds the forces of that constant wrench at zero (free, they turn with a rotation common to every
    #: transducer: ``refit._hold_offset_shift``)
    joint_holds_offset_shift: ClassVar[bool] = False
    #: with free transducer rotations the effect shows as a common tilt of the fitted frames
    #: (``faces.design_check``), which the diagnosis scores as the effect's design face
    design_face: ClassVar[bool] = False
    #: the simulators its injector and shapes work in: "hexapod" (``ftcal_nlp.sim``), "free" (``ftcal_nlp.sim.free``,
    #: a transducer with a free load: it needs nothing of a hexapod)
    applies_to: ClassVar[frozenset] = frozenset({"hexapod"})
    #: the datasets the diagnosis has model faces for: "hexapod" (standing / hanging / swing faces above),
    #: "free" (free-load faces)
    diagnosed_on: ClassVar[frozenset] = frozenset({"hexapod"})

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "magnitude" not in cls.__dict__ and "injector_cls" in cls.__dict__:
            cls.magnitude = getattr(cls.injector_cls, "magnitude", cls.magnitude)

    def variants(self) -> tuple[Effect, ...]:
        """The same effect with faces of different flexibility in its correlate (issue 13, item 4);
        attribution scores each and keeps the one that predicts held-out data best. Default: itself."""
        return (self,)

    def joint_variant(self) -> Effect:
        """The variant the joint refit uses (``diagnose/refit.py``); default: this one."""
        return self

    def joint_variants(self) -> tuple[Effect, ...]:
        """Variants the joint refit chooses among by the hanging face's held-out residual (the hanging
        legs sweep every shaft angle, so a flexible face is cheap there); default: ``joint_variant``."""
        return (self.joint_variant(),)

    @property
    def variant(self) -> dict:
        """The keyword arguments that rebuild this variant (``type(self)(**variant)``)."""
        return {}

    @property
    def label(self) -> str:
        """The effect's name with its variant, e.g. ``casing_load (harmonics=2)``."""
        return self.name + (" (" + ", ".join(f"{k}={v}" for k, v in self.variant.items()) + ")" if self.variant else "")

    def injector(self, scale: float | None = None, seed: int = 0) -> EffectInjector:
        return self.injector_cls(scale=scale, seed=seed)

    # ---- standing face (A)
    def standing_params(self, ctx: AugContext) -> ParamBlock | None:
        return None

    def standing(self, eta, pose: PoseSym, ctx: AugContext):
        """``(c, zmap, extra)``: corrected readings (K list of (6,)), a 3x3 map of the up
        vector (``z~ = zmap z``; None: unchanged) and an extra wrench (6,) (or None),
        all linear in the pose's feature symbols."""
        return pose.w, None, None

    def standing_from_hanging(self, hanging: dict, ctx: AugContext) -> dict:
        """Standing-face parameters that mean the same as parameters of the hanging face
        (index into ``standing_params`` -> value from ``hanging``, names as the hanging face's
        ``LinearFace.names``). A joint refit holds them at the hanging estimates: the hanging legs
        sweep every shaft angle and load direction, standing poses see only the sum in B."""
        return {}

    def standing_prior_from_hanging(self, ctx: AugContext) -> dict:
        """Standing-face parameters the hanging face also estimates, where neither kind alone determines them all
        (index into ``standing_params`` -> the hanging face's name). A joint refit fits them once on both kinds: the
        hanging estimate with its information enters the standing fit as a prior (``standing_fit.EtaPrior``), not
        held (``standing_from_hanging``): a sensor matrix read on the leg's weight in two hanging directions and on the
        ground's force in the standing poses."""
        return {}

    def standing_balance(self, balance: str) -> str:
        """The balance the augmented standing problem uses (only ``moving_com`` changes it)."""
        return balance

    # ---- linear faces (hanging, walking swing): first-order effect on the residuals
    def hanging_features(self, legs: list[HangingLeg]) -> LinearFace | None:
        return None

    def swing_features(self, legs: list[HangingLeg]) -> LinearFace | None:
        return None

    # ---- the free-load face (``free_faces.py``: the contract); no free face by default
    #: the correlate its free-load residual lies along (None: ``explains``); "joint" means "joint:<name>"
    free_explains: ClassVar[str | None] = None
    #: the free shapes are nested, each holding the one before: a larger one must beat the one kept by a paired z
    #: (``diagnose/chain.py``, ``NESTED_Z``), not only by a smaller held-out sum of squares
    free_nested: ClassVar[bool] = False

    def free_shapes(self, ctx) -> tuple[dict, ...]:
        """The grid of nonlinear shape parameters of the free face (``free_faces.py``); ``()``: none."""
        return ()

    def free_face(self, ctx, shape: dict):
        """A :class:`~.free_faces.FreeFace` (design columns linear in the effect's parameters) for ``shape``, or
        None where it does not apply to these data."""
        return None

    def free_refine(self, ctx, shape: dict, resid: np.ndarray) -> dict | None:
        """A refined shape from the grid's best ``shape`` and the current residual (N, 6); None: none (the default)."""
        return None

    def free_refine_near(self, ctx, shape: dict) -> tuple[dict, ...]:
        """Shapes near the grid's best ``shape`` spanning what :meth:`free_refine` searches: the diagnosis tunes the
        shape per cross-validation fold among them (their faces), on the fold's training blocks alone
        (``free_faces.py``); ``()`` (the default): the refined shape is scored as tuned on every sample."""
        return ()

    def free_correct(self, ctx, shape: dict, beta: np.ndarray) -> np.ndarray:
        """Readings (N, 6) of ``ctx`` corrected for the effect with parameters ``beta``: ``y - X beta``."""
        face = self.free_face(ctx, shape)
        return ctx.y if face is None else ctx.y - face.wrench(beta)

    # ---- the free-load correction of a new recording (``correction.py``): the hooks its generic flow calls
    #: the correction follows the readings' own clock between changes of load (re-sampling, relaxation, a rate of
    #: turn): the recording to correct must be a stream with t in seconds (``correction.stream_members``)
    follows_stream_clock: ClassVar[bool] = False
    #: the keys of :meth:`free_reference` (read back into a new recording's ``ctx.extra`` under the same keys)
    free_reference_keys: ClassVar[tuple[str, ...]] = ()

    def free_reference(self, ctx, shape: dict) -> dict:
        """What the free face computes from the whole calibration session ``ctx`` that a new recording cannot
        (``meta.effect.legs.X.reference``, keys :attr:`free_reference_keys`); default nothing."""
        return {}

    def free_require(self, ctx, shape: dict, leg: str, where: str) -> None:
        """A DataFormatError naming the column when the recording ``ctx`` to correct lacks a signal this effect's
        correction needs; default nothing needed."""

    def free_session_check(self, ctx, shape: dict, reference: dict, leg: str, where: str) -> None:
        """A warning when the correction of ``ctx`` extrapolates what the calibration session saw; default none."""

    # ---- the correction for `correct`
    def correct(self, cal, block: dict, ctx: AugContext, w: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, t_h: np.ndarray,
                *, with_cov: bool = True, source: str = "calibration"):
        """``(w', R_WB', cov)``: readings (N, K, 6) and orientations (N, 3, 3) of samples at ``t_h`` hours since
        the block's ``t_ref_s`` corrected for this effect with the parameters of ``block`` (``meta["effect"]``),
        and the covariance (N, K, 6, 6) of the corrected readings (None: not propagated). A sensor effect: its
        standing face (:func:`.faces.correct_by_face`); a body effect acts on the body as a whole, not on the
        transducers' readings: per-foot wrenches are unchanged (logged)."""
        if self.kind == "body":
            log.info("%s: %s acts on the body, not on the transducers' readings: per-foot wrenches are unchanged", source, self.name)
            return w, R_WB, None
        if "hexapod" not in self.diagnosed_on:   # no standing face to evaluate (a free-load effect: ``free_correct``)
            log.info("%s: %s has no hexapod face: readings unchanged", source, self.name)
            return w, R_WB, None
        return correct_by_face(self, cal, block, ctx, w, phi, R_WB, t_h, with_cov=with_cov, source=source)

    def __repr__(self) -> str:
        return f"<effect {self.name}>"


def corrects_by_face(effect: Effect) -> bool:
    """Whether ``effect``'s correction is its standing face evaluated on the samples (a sensor effect with a hexapod
    face that keeps ``Effect.correct``), so that it can be evaluated together with others (``Combined.correct``)."""
    return effect.kind == "sensor" and "hexapod" in effect.diagnosed_on and type(effect).correct is Effect.correct
