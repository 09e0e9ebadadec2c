"""The simulator face of an effect: the injection hook and the injectors' bases.

The simulator computes, for every recording, the true applied wrench ``w_a`` of
each leg (report eq. 1) and the true orientation ``R_WB``. Readings are then

    w_m = inject_readings(w_a + w_o) + n,    R_meas = inject_orientation(R_WB exp([delta]))

where ``n`` is sensor noise and ``delta`` motion-capture jitter. An injector sees an
:class:`InjectionContext` and returns modified arrays; it never changes the truth it
is compared against. Each effect unit (``ftcal_nlp/effects/<name>.py``) declares its
injector (a subclass of :class:`EffectInjector`: ``scale`` in the unit of its
:class:`Magnitude`, ``seed`` fixing its own random parameters) and its off-face
validation shapes (subclasses of :class:`OffFaceInjector`, which say what a correct
diagnosis should call them: ``expect``, ``expect_legs``).

Sizes are in ``Magnitude``: a realistic range for an ATI Gamma on an 8 kg robot and
a test size at which the effect is clearly detectable.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Protocol, runtime_checkable

import numpy as np

HOUR_S = 3600.0
REF_FORCE_N = 20.0    # reference load for loads-dependent effects (a leg's stance load is ~13-25 N)
REF_TORQUE_NM = 2.0

EXPECT_NONE = "none"
EXPECT_UNEXPLAINED = "unexplained"


@dataclass(frozen=True)
class InjectionContext:
    """What an injector may look at, for one recording of N samples and K legs.

    ``kind``: hanging | standing | walking; ``name``: recording name; ``t`` (N,) s;
    ``phi`` (N, K) rad; ``R_WB`` (N, 3, 3) true body orientation; ``applied``
    (N, K, 6) true applied wrench in ft_k (N, N*m); ``pose_index`` (N,) int,
    the standing pose a sample belongs to (-1 outside standing); ``truth`` the
    :class:`~ftcal_nlp.sim.robot_model.TrueRobot`; ``rng`` a generator private
    to this injector and recording.
    """

    kind: str
    name: str
    t: np.ndarray
    phi: np.ndarray
    R_WB: np.ndarray
    applied: np.ndarray
    pose_index: np.ndarray
    truth: Any
    rng: np.random.Generator


@runtime_checkable
class Injector(Protocol):
    """An effect added to simulated readings. ``name`` is its canonical effect name
    (``OUTPUT_FORMAT.md``), written to ``truth.json`` as ``effect``; ``scale`` its size."""

    name: str
    scale: float

    def readings(self, ctx: InjectionContext, w: np.ndarray) -> np.ndarray:
        """Noise-free readings (N, K, 6) in ft_k -> modified readings (same shape)."""
        ...

    def orientation(self, ctx: InjectionContext, R_meas: np.ndarray) -> np.ndarray:
        """Motion-capture orientation (N, 3, 3) -> modified (same shape)."""
        ...


class NoEffect:
    """Identity injector; a base class whose methods effects override as needed.

    Besides the two protocol methods an injector may define ``robot(robot) ->
    Robot``: the robot description written to ``robot.toml`` (e.g. a wrongly
    weighed mass); the simulation itself always uses the true robot.
    """

    name = "none"
    scale = 0.0

    def readings(self, ctx: InjectionContext, w: np.ndarray) -> np.ndarray:
        return w

    def orientation(self, ctx: InjectionContext, R_meas: np.ndarray) -> np.ndarray:
        return R_meas

    def robot(self, robot):
        return robot


def apply_readings(effects: tuple, ctx_args: dict, w: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray:
    """Apply each injector's ``readings`` in turn (each with its own generator)."""
    for eff, rng in zip(effects, rngs):
        w = eff.readings(InjectionContext(rng=rng, **ctx_args), w)
    return w


def apply_orientation(effects: tuple, ctx_args: dict, R: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray:
    """Apply each injector's ``orientation`` in turn."""
    for eff, rng in zip(effects, rngs):
        R = eff.orientation(InjectionContext(rng=rng, **ctx_args), R)
    return R


def apply_robot(effects: tuple, robot):
    """The robot description as the user would write it (injectors with a ``robot`` method)."""
    for eff in effects:
        if hasattr(eff, "robot"):
            robot = eff.robot(robot)
    return robot


@dataclass(frozen=True)
class Magnitude:
    """``unit`` of ``scale``; ``realistic`` (lo, hi) range; ``test`` a clearly detectable size."""

    unit: str
    realistic: tuple[float, float]
    test: float


class EffectInjector(NoEffect):
    """Base of the library's injectors: ``scale`` in the effect's unit (default: its
    ``magnitude.test``), ``seed`` fixes the effect's own random parameters (the same
    for every recording of a session; the generator is seeded by seed and name)."""

    name = "none"
    magnitude: ClassVar[Magnitude] = Magnitude("", (0.0, 0.0), 0.0)

    def __init__(self, scale: float | None = None, seed: int = 0):
        self.scale = float(self.default_scale() if scale is None else scale)
        self.seed = int(seed)
        self.rng = np.random.default_rng(np.random.SeedSequence([self.seed, _name_key(self.name)]))

    @classmethod
    def default_scale(cls) -> float:
        return cls.magnitude.test

    def drawn(self, key: str, K: int, draw: Callable[[int], np.ndarray]) -> np.ndarray:
        """The injector's own random parameters of ``K`` legs, ``draw(K)`` (from ``self.rng``) once and kept as
        attribute ``key``: the same for every recording of a session, drawn again only for another ``K``."""
        v = self.__dict__.get(key)
        if v is None or len(v) != K:
            v = draw(K)
            setattr(self, key, v)
        return v

    def __repr__(self) -> str:
        return f"{type(self).__name__}(scale={self.scale:g}, seed={self.seed})"


def _name_key(name: str) -> int:
    return int.from_bytes(name.encode()[:8].ljust(8, b"\0"), "little")


def variant_key(*parts: str) -> int:
    """A process-independent 32-bit key of names (CRC-32; ``hash`` is salted per process)."""
    return zlib.crc32("/".join(parts).encode())


class OffFaceInjector(EffectInjector):
    """Base of the off-face injectors (issue 13, item 5: effects whose shapes differ from the diagnosis'
    model faces): an :class:`EffectInjector` whose generator is seeded by ``seed`` and the whole name (so a
    variant never shares the draws of the library injector it resembles), with what a correct diagnosis
    should say (``expect``: a library effect's name, ``"unexplained"`` or ``"none"``; ``expect_legs``)."""

    expect: ClassVar[str] = EXPECT_NONE

    def __init__(self, scale: float | None = None, seed: int = 0, **kwargs):
        super().__init__(scale, seed, **kwargs)
        self.rng = np.random.default_rng(np.random.SeedSequence([self.seed, variant_key(self.name)]))

    @property
    def expect_legs(self) -> tuple[str, ...]:
        return ()


def rotvec_rotate(delta: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by the rotation vectors ``delta`` (..., 3) (Rodrigues)."""
    th = np.linalg.norm(delta, axis=-1, keepdims=True)
    ths = np.where(th < 1e-12, 1.0, th)
    n = delta / ths
    c, s = np.cos(th), np.sin(th)
    return v * c + np.cross(n, v) * s + n * np.sum(n * v, axis=-1, keepdims=True) * (1 - c)


def shaft_speed(t: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """``d phi / dt`` (N, K) by central differences on the session clock."""
    if len(t) < 2:
        return np.zeros_like(phi)
    return np.gradient(phi, t, axis=0)


def distribute_over_feet(w_B: np.ndarray, ctx: InjectionContext) -> np.ndarray:
    """Reading changes (N, K, 6) that carry the external wrench ``w_B`` (N, 6; B axes,
    about the body-without-legs CoM) through the feet in contact (least-norm forces:
    ``sum_k dF_k = -f``, ``sum_k (foot_k - c) x dF_k = -tau``, read as ``[dF; foot x dF]`` in ft_k)."""
    truth = ctx.truth
    K = len(truth.legs)
    u_B = -ctx.R_WB[:, 2, :]
    f_leg = truth.weights_N[None, :, None] * np.einsum("kji,nj->nki", truth.R, u_B)
    f_ground = ctx.applied[..., :3] - f_leg
    contact = np.linalg.norm(f_ground, axis=-1) > 1e-6                       # (N, K)
    foot_ft = truth.foot_ft(ctx.phi)                                         # (N, K, 3)
    lever = truth.ft_to_body(foot_ft) - truth.com_body_m                     # (N, K, 3)
    N = len(ctx.t)
    A = np.zeros((N, 6, 3 * K))
    eye = np.eye(3)
    for k in range(K):
        m = contact[:, k, None, None]
        A[:, 0:3, 3 * k : 3 * k + 3] = np.where(m, eye, 0.0)
        lx = np.zeros((N, 3, 3))
        l = lever[:, k]
        lx[:, 0, 1], lx[:, 0, 2], lx[:, 1, 0], lx[:, 1, 2], lx[:, 2, 0], lx[:, 2, 1] = -l[:, 2], l[:, 1], l[:, 2], -l[:, 0], -l[:, 1], l[:, 0]
        A[:, 3:6, 3 * k : 3 * k + 3] = np.where(m, lx, 0.0)
    AAt = A @ np.swapaxes(A, 1, 2) + 1e-12 * np.eye(6)
    dF = np.einsum("nji,nj->ni", A, np.linalg.solve(AAt, -w_B[..., None])[..., 0]).reshape(N, K, 3)
    dF_ft = np.einsum("kji,nkj->nki", truth.R, dF)                           # R_k^T dF
    return np.concatenate([dF_ft, np.cross(foot_ft, dF_ft)], axis=-1)
