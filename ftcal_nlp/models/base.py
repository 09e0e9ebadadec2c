"""Error-model plug-ins: what a model declares (report Sec. III-B, IV-2).

An error model says how the unknowns of the standing stage map to the
transducer-to-CoM transforms of eq. 2: for every leg k the rotation
``R_k = R_ft_k^B`` (ft_k -> B) and the translation ``p'_k`` (origin of ft_k
relative to the CoM of the body without legs, B axes; the report's
``p'_k = R_tilde_k (p_tilde_k + p_B^C)`` after its change of variable). A model
is a small class with a ``name``, a ``description`` and a ``build(ctx)`` that
returns a :class:`ModelSpec`: CasADi SX decision variables with initial values
and bounds, constraints, the K rotations and K translations as expressions of
those variables, and the degrees of freedom.

Rotations that a model estimates are best declared with :func:`so3_variable`:
nine matrix entries with the exact SO(3) constraints ``R^T R = I`` (six
equations) and ``det R >= 0`` (with orthogonality this is ``det R = +1``; an
inequality keeps the constraint Jacobian full rank, where the equation
``det R = 1`` would repeat the trace of the orthogonality equations).

Optional parts of a spec: ``offsets`` (K 6-vectors, the transducer offsets
``w_o`` when a model re-estimates them, Sec. V; otherwise the prior's) and
``com_body`` (the CoM of the body without legs in B, for models whose
translations are nominal transducer positions less that CoM).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import casadi as ca
import numpy as np

from ..core.calibration import Calibration


@dataclass(frozen=True)
class ModelContext:
    """What a model may use to declare itself.

    ``R_nominal`` (K, 3, 3) and ``p_nominal`` (K, 3) m: the design-file poses of
    the transducers in B (``robot.toml``); ``prior``: the calibration the
    standing stage starts from (offsets, leg weights, leg CoM curves; for the
    offsets-only model also the rotations and translations it keeps).
    """

    legs: tuple[str, ...]
    R_nominal: np.ndarray
    p_nominal: np.ndarray
    prior: Calibration

    @property
    def K(self) -> int:
        return len(self.legs)


@dataclass(frozen=True)
class ModelSpec:
    """A model built for one robot: variables, their map to (R_k, p'_k), constraints, DOF.

    ``x`` (n,) SX symbols with ``x0``, ``lbx``, ``ubx`` (n,); ``R`` K SX 3x3
    (ft_k -> B) and ``p_prime`` K SX 3-vectors (m, B axes), expressions of
    ``x``; ``g`` (m,) SX constraints with bounds ``lbg``, ``ubg`` (equal bounds
    are equations); ``names`` (n,) labels of the entries of ``x``; ``dof`` the
    number of free directions (n less the equations when None);
    ``dof_label`` how Table I prints it (e.g. ``"18+18"``).
    """

    x: ca.SX
    x0: np.ndarray
    lbx: np.ndarray
    ubx: np.ndarray
    R: tuple
    p_prime: tuple
    g: ca.SX = field(default_factory=lambda: ca.SX(0, 1))
    lbg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ubg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    names: tuple[str, ...] = ()
    offsets: tuple | None = None
    com_body: ca.SX | None = None
    dof: int | None = None
    dof_label: str | None = None

    @property
    def n_eq(self) -> int:
        return int(np.sum(np.asarray(self.lbg) == np.asarray(self.ubg)))

    @property
    def n_dof(self) -> int:
        return int(self.dof) if self.dof is not None else int(self.x.numel()) - self.n_eq

    def validate(self, K: int, where: str) -> None:
        n = int(self.x.numel())
        for key in ("x0", "lbx", "ubx"):
            a = np.asarray(getattr(self, key), float)
            if a.shape != (n,):
                raise ValueError(f"{where}: {key} has shape {a.shape}, expected ({n},) like x")
        if not np.all(np.asarray(self.lbx) <= np.asarray(self.x0)) or not np.all(np.asarray(self.x0) <= np.asarray(self.ubx)):
            raise ValueError(f"{where}: x0 outside [lbx, ubx]")
        m = int(self.g.numel())
        if np.shape(self.lbg) != (m,) or np.shape(self.ubg) != (m,):
            raise ValueError(f"{where}: lbg/ubg must have shape ({m},) like g")
        if len(self.R) != K or any(r.shape != (3, 3) for r in self.R):
            raise ValueError(f"{where}: R must hold {K} 3x3 expressions (one per leg)")
        if len(self.p_prime) != K or any(p.numel() != 3 for p in self.p_prime):
            raise ValueError(f"{where}: p_prime must hold {K} 3-vectors (one per leg)")
        if self.offsets is not None and (len(self.offsets) != K or any(o.numel() != 6 for o in self.offsets)):
            raise ValueError(f"{where}: offsets must be None or hold {K} 6-vectors")
        if self.names and len(self.names) != n:
            raise ValueError(f"{where}: names has {len(self.names)} entries, x has {n}")


class ErrorModel:
    """Base of every error model. Subclasses set ``name``/``description`` and implement ``build``.

    Attributes used by the report's baseline solver (built-in models only):
    ``baseline_rotations`` in {"each", "nominal", "prior"} and
    ``baseline_translations`` in {"each", "common", "prior"}, ``baseline_offsets``.
    """

    name: ClassVar[str] = ""
    description: ClassVar[str] = ""
    baseline_rotations: ClassVar[str | None] = None
    baseline_translations: ClassVar[str | None] = None
    baseline_offsets: ClassVar[bool] = False

    def build(self, ctx: ModelContext) -> ModelSpec:  # pragma: no cover - interface
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r})"


# ----------------------------------------------------------------------------- helpers for model authors


@dataclass(frozen=True)
class Block:
    """A group of decision variables with its constraints; blocks concatenate into a spec."""

    x: ca.SX
    x0: np.ndarray
    lbx: np.ndarray
    ubx: np.ndarray
    names: tuple[str, ...]
    g: ca.SX = field(default_factory=lambda: ca.SX(0, 1))
    lbg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ubg: np.ndarray = field(default_factory=lambda: np.zeros(0))


def so3_variable(name: str, R0: np.ndarray) -> tuple[ca.SX, Block]:
    """A rotation as nine free entries with exact SO(3) constraints.

    Returns ``(R, block)``: ``R`` the 3x3 SX matrix (row-major entries
    ``name[ij]``), ``block`` its variables started at ``R0`` with the six
    equations ``(R^T R - I)_ij = 0, i <= j`` and ``det R >= 0``.
    """
    x = ca.SX.sym(name, 9)
    R = ca.reshape(x, 3, 3).T  # x holds the rows of R
    RtR = ca.mtimes(R.T, R)
    eqs = [RtR[i, j] - (1.0 if i == j else 0.0) for i in range(3) for j in range(i, 3)]
    g = ca.vertcat(*eqs, ca.det(R))
    lbg = np.r_[np.zeros(6), 0.0]
    ubg = np.r_[np.zeros(6), np.inf]
    names = tuple(f"{name}[{i}{j}]" for i in range(3) for j in range(3))
    R0 = np.asarray(R0, float)
    return R, Block(x, R0.reshape(9), np.full(9, -np.inf), np.full(9, np.inf), names, g, lbg, ubg)


def vector_variable(name: str, x0: np.ndarray, bound: float = np.inf, labels=("x", "y", "z")) -> tuple[ca.SX, Block]:
    """A free vector started at ``x0`` within ``x0 +- bound``; returns ``(v, block)``.

    ``labels`` name the components (``name.label``); indices when their number differs.
    """
    x0 = np.asarray(x0, float).reshape(-1)
    x = ca.SX.sym(name, x0.size)
    lab = labels if len(labels) == x0.size else [str(i) for i in range(x0.size)]
    names = tuple(f"{name}.{c}" for c in lab)
    return x, Block(x, x0, x0 - bound, x0 + bound, names)


def make_spec(blocks: list[Block], R, p_prime, **kw) -> ModelSpec:
    """Concatenate ``blocks`` into a :class:`ModelSpec` with the given maps and options."""
    def cat(xs: list[ca.SX]) -> ca.SX:
        return ca.vertcat(*xs) if xs else ca.SX(0, 1)

    return ModelSpec(
        x=cat([b.x for b in blocks]),
        x0=np.concatenate([b.x0 for b in blocks]) if blocks else np.zeros(0),
        lbx=np.concatenate([b.lbx for b in blocks]) if blocks else np.zeros(0),
        ubx=np.concatenate([b.ubx for b in blocks]) if blocks else np.zeros(0),
        R=tuple(ca.SX(r) for r in R),
        p_prime=tuple(ca.SX(p) for p in p_prime),
        g=cat([b.g for b in blocks if b.g.numel()]),
        lbg=np.concatenate([b.lbg for b in blocks]) if blocks else np.zeros(0),
        ubg=np.concatenate([b.ubg for b in blocks]) if blocks else np.zeros(0),
        names=tuple(n for b in blocks for n in b.names),
        **kw,
    )
