"""What an effect of the library is: one plug-in with two faces (issue 7).

Face (a), the injector, adds the effect to simulated readings (the hook of
``ftcal_nlp.sim.effects``: ``readings(ctx, w)``, ``orientation(ctx, R)``,
``robot(robot)``); its ``scale`` is the effect's size in the unit of
:class:`Magnitude`. The injectors, their base :class:`EffectInjector`, their
formulas and their sizes live in the simulator, :mod:`ftcal_nlp.sim.injectors`
(re-exported here); an :class:`Effect` names its injector class (``injector_cls``)
and takes its ``magnitude`` from it.

Face (b), the augmentation, adds a few parameters ``eta`` to the calibration
model so that it can absorb the effect:

* standing (report eq. 8 with the balance of physics.py (E) or eq. 9): the
  balance residual of pose p becomes

      r_p = sum_k Ad_k (c_k(w_m,pk; eta) - w_o,k) - M_b g [z~_p(eta); 0] + e_p(eta)     (A)

  with corrected readings ``c_k``, a corrected up-vector ``z~`` and an extra
  wrench ``e_p`` (B axes, about the reference point); ``eta = 0`` gives back the
  calibration model. :meth:`Effect.standing` returns ``(c_k, z~, e_p)`` as
  CasADi expressions of ``eta`` and of one pose's data (:class:`PoseSym`).
* hanging (report eqs. 4-7) and walking swing (a foot in the air reads only its
  leg's weight): the effect is linear in ``eta`` to first order, so it enters
  as features ``X`` (N, 6, m) regressed on the residuals of the fitted model
  (:meth:`Effect.hanging_features`, :meth:`Effect.swing_features`).

Sizes are in ``Magnitude``: a realistic range for an ATI Gamma on an 8 kg
robot and a test size at which the effect is clearly detectable.

This module holds face (b)'s building blocks: :class:`Effect`, the symbols and
contexts of the faces (:class:`PoseSym`, :class:`AugContext`, :class:`ParamBlock`,
:class:`HangingLeg`, :class:`LinearFace`) and :func:`per_leg_face`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ...sim.effects import NoEffect
from ...sim.injectors import (  # noqa: F401  (re-exported: the injector face lives in the simulator)
    HOUR_S,
    REF_FORCE_N,
    REF_TORQUE_NM,
    EffectInjector,
    Magnitude,
    rotvec_rotate,
    shaft_speed,
)

WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")
TIME_BASIS = 4      # smooth time basis of the standing features (flexible drift faces choose how many terms)
HARMONICS = 6       # harmonics of the shaft angle in the standing features (flexible shaft-angle faces)


def legendre_time(t: np.ndarray, lo: float, hi: float, degrees) -> np.ndarray:
    """Legendre polynomials ``P_j`` (j in ``degrees``) of the time ``t`` scaled to [-1, 1] over [lo, hi],
    (N, len(degrees)); zeros when the span is empty. The smooth time basis of the drift faces, the
    standing features (``PoseSym.tb``) and the floor's structure columns."""
    t = np.asarray(t, float)
    tau = 2.0 * (t - lo) / (hi - lo) - 1.0 if hi > lo else np.zeros(len(t))
    degrees = list(degrees)
    return np.stack([np.polynomial.legendre.legval(tau, np.eye(j + 1)[j]) for j in degrees], axis=1) if degrees else np.zeros((len(t), 0))


@dataclass(frozen=True)
class PoseSym:
    """One standing pose as CasADi symbols of its *features*, legs in order.

    A standing face must be linear in these symbols (products it needs are
    features of their own), so that the residual is ``r_p = M(theta) phi_p`` and
    eq. 8 reduces to moments of ``phi`` (see ``standing_fit.py``, which checks it).

    ``w`` K raw readings (6,) in ft_k; ``z`` (3,) measured up direction in B
    (``R_WB^T e_z``); ``R_HB`` (3, 3) measured orientation without heading;
    ``t_h`` and ``t_h2`` hours since the hanging recordings (where the offsets
    were estimated) and its square; ``prev`` K raw readings of the previous pose
    (equal to ``w`` when there is none); ``cphi``/``sphi`` (K,) cos and sin of
    the shaft angles; ``w2`` K squared readings (6,); ``nfw`` K products
    ``(n_k . f_k) w_k`` with ``n_k`` the design-vertical ft axis; ``rcom`` K leg
    CoMs (3,) at the shaft angles (hanging curves, ft_k, m); ``rz`` K 3x3
    products ``r_a z_l``; ``tb`` (TIME_BASIS,) a smooth basis of time over the standing
    session (Legendre P_1.. of the scaled time); ``harm`` per harmonic m = 1..HARMONICS the
    pair (cos m phi, sin m phi), each (K,); ``step`` (1,) 1 after the change point of the
    calibration's standing residual (``views.change_point``), else 0.
    """

    w: list
    z: Any
    R_HB: Any
    t_h: Any
    t_h2: Any
    prev: list
    cphi: Any
    sphi: Any
    w2: list
    nfw: list
    rcom: list
    rz: list
    tb: Any = None
    harm: list = None
    step: Any = None


@dataclass(frozen=True)
class AugContext:
    """What an augmentation may use: legs, the model's offsets ``w_o`` (K expressions
    or DM), nominal transducer rotations (K, 3, 3), leg weights ``m_k g`` (K,) N,
    ``g``, and the hanging CoM curves (for inertial effects)."""

    legs: tuple[str, ...]
    w_o: list
    R_nominal: np.ndarray
    leg_weight_N: np.ndarray
    g: float

    @classmethod
    def from_calibration(cls, cal, legs: tuple[str, ...], R_nominal: np.ndarray) -> AugContext:
        """The context of a finished calibration: its offsets (numbers) and leg weights."""
        import casadi as ca

        return cls(legs, [ca.DM(np.asarray(cal.legs[k].offset, float)) for k in legs], np.asarray(R_nominal, float),
                   np.array([cal.legs[k].leg_weight_N for k in legs]), cal.g)

    @property
    def K(self) -> int:
        return len(self.legs)

    def vertical_axis(self, k: int) -> np.ndarray:
        """The ft_k axis that is vertical in the design (``R_nom^T e_z``)."""
        return self.R_nominal[k].T @ np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class ParamBlock:
    """Parameters of an augmentation: ``names`` (m,), start ``x0`` (zeros: no effect) and
    bounds. Bounds are physical plausibility (several times the largest realistic
    size): without them a face can mimic another effect with absurd values, e.g.
    a chassis flex of 70 degrees reproducing a constant force."""

    @classmethod
    def bounded(cls, names, bound: float) -> ParamBlock:
        names = tuple(names)
        return cls(names, np.zeros(len(names)), np.full(len(names), -float(bound)), np.full(len(names), float(bound)))

    names: tuple[str, ...]
    x0: np.ndarray = None
    lb: np.ndarray = None
    ub: np.ndarray = None

    def __post_init__(self):
        m = len(self.names)
        if self.x0 is None:
            object.__setattr__(self, "x0", np.zeros(m))
        if self.lb is None:
            object.__setattr__(self, "lb", np.full(m, -np.inf))
        if self.ub is None:
            object.__setattr__(self, "ub", np.full(m, np.inf))

    @property
    def m(self) -> int:
        return len(self.names)


@dataclass(frozen=True)
class HangingLeg:
    """One leg's hanging (or walking swing) samples for the linear faces.

    ``e`` (N, 6) residual of the fitted model; ``t`` (N,) s; ``phi`` (N,) rad;
    ``omega`` (N,) shaft speed rad/s; ``rec`` (N,) recording index; ``f`` (N, 3)
    the fitted leg weight vector in ft_k (N); ``r`` (N, 3) leg CoM at phi (m);
    ``r_dd`` (N, 3) its second derivative in phi (m/rad^2); ``mg`` leg weight N;
    ``t_ref`` s, time the offsets refer to; ``k`` leg index; ``n_vert`` (3,) the
    design-vertical ft axis; ``R_cal`` (3, 3) the calibration's ft_k -> B rotation
    (walking swing; None for hanging, which never uses it).
    """

    leg: str
    k: int
    e: np.ndarray
    t: np.ndarray
    phi: np.ndarray
    omega: np.ndarray
    rec: np.ndarray
    f: np.ndarray
    r: np.ndarray
    r_dd: np.ndarray
    mg: float
    g: float
    t_ref: float
    n_vert: np.ndarray
    R_cal: np.ndarray | None = None

    @property
    def applied(self) -> np.ndarray:
        """The modelled applied wrench ``[f; r x f]`` (N, 6)."""
        return np.hstack([self.f, np.cross(self.r, self.f)])


class Effect:
    """One effect of the library: an injector class and the augmentation faces.

    Subclasses set ``name`` (canonical, ``OUTPUT_FORMAT.md``), ``description``,
    ``explains`` (the dependence localisation should find), ``injector_cls`` (from
    :mod:`ftcal_nlp.sim.injectors`) and ``magnitude`` (``injector_cls.magnitude``);
    they override the faces they have.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    explains: ClassVar[str | None] = None
    magnitude: ClassVar[Magnitude] = Magnitude("", (0.0, 0.0), 0.0)
    injector_cls: ClassVar[type] = NoEffect
    #: the calibration settings under which the standing face is meaningful
    needs_report_balance: ClassVar[bool] = False
    #: the effect acts while hanging, so the hanging offsets absorbed part of it: the standing
    #: face gets a constant wrench in B (6 parameters) for the shifted offsets
    shifts_offsets: ClassVar[bool] = False

    def variants(self) -> tuple[Effect, ...]:
        """The same effect with faces of different flexibility in its correlate (issue 13, item 4);
        attribution scores each and keeps the one that predicts held-out data best. Default: itself."""
        return (self,)

    def joint_variant(self) -> Effect:
        """The variant the joint refit uses (``diagnose/joint.py``); default: this one."""
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

    def standing_balance(self, balance: str) -> str:
        """The balance the augmented standing problem uses (only ``moving_com`` changes it)."""
        return balance

    # ---- linear faces (hanging, walking swing): first-order effect on the residuals
    def hanging_features(self, legs: list[HangingLeg]) -> LinearFace | None:
        return None

    def swing_features(self, legs: list[HangingLeg]) -> LinearFace | None:
        return None

    def __repr__(self) -> str:
        return f"<effect {self.name}>"


@dataclass(frozen=True)
class LinearFace:
    """Features of a linear face: ``blocks[i]`` (N_i, 6, q) for ``legs[i]``; ``per_leg``: each
    leg has its own q parameters (m = K q), else the q parameters are shared (m = q)."""

    blocks: list
    names: tuple
    per_leg: bool


def per_leg_face(legs: list[HangingLeg], make, labels) -> LinearFace:
    """``make(leg) -> (N, 6, q)``; parameters separate per leg, named ``leg.label``."""
    K = max(l.k for l in legs) + 1 if legs else 0
    names = [""] * K
    for l in legs:
        names[l.k] = l.leg
    return LinearFace([make(l) for l in legs], tuple(f"{n or k}.{c}" for k, n in enumerate(names) for c in labels), True)
