"""Per-leg checks that need no effect library (issue 13, item 3): a free linear map of each
leg's readings on the standing poses, and each leg's weight and CoM refit on its own swing phases.

Both look for a gap that belongs to one leg and say which leg and which components, whatever
the cause: swapped or mis-signed axes, gain errors and crosstalk (check 1), a leg whose mass
changed after it hung (check 2). Neither knows the simulator's injectors.

Check 1: free linear map per leg (standing poses, cross-validated)
--------------------------------------------------------------------
The calibrated balance (``balance.residual``, exact or report, B axes) of pose p is

    r_p = g_p + sum_k [R_k f~_pk; R_k tau~_pk + p'_k x R_k f~_pk],      w~ = w_m - w_o = [f~; tau~],

``g_p`` the weight terms (held at the calibration's values here). In the check each leg's force
part ``R_k f~`` and torque part ``R_k tau~`` get a map ``MF_k``, ``MT_k`` (3x3, ft_k -> B), and the
balance a free constant ``c`` (6,), which takes up offset changes common to the poses (readings
with swapped axes carry their offsets swapped too), and a free change ``dW`` of the body's weight
(a leg weighed wrong when it hung puts its error into ``M_b g``):

    r_p = g_p + sum_k [MF_k f~_pk; MT_k tau~_pk + p'_k x MF_k f~_pk] + c - dW [z_p; 0].

A part that is *free* has all 9 entries of its map free; every other part stays a rotation,
refitted to first order about the calibration, ``MF_k = (I + [d_k]) R_k`` (one ``d_k`` for both
parts of a leg with none free), and every ``p'_k`` gets an increment ``dp_k``. So the base model
(no part free) is the calibration refitted to first order on the training poses, and a fault on
one leg cannot hide in the rotations the calibration gave the others to compensate it. The
residual is linear in all of these increments: least squares in the K-norm of eq. 8
(``K = diag(1, 1, 1, 10, 10, 10)``), on the normal equations per fold. Every model is
cross-validated on one seeded split of the poses (``folds``): ``H = sum_p ||r_p||_K^2`` over
held-out poses.

Forward selection over candidates ``(leg, part)``, part ``force``, ``torque`` or ``both``: a
candidate is significant when freeing it lowers the held-out residual far beyond what noise does,

    H(new) / H(current) < max_ratio     and     the one-sided Wilcoxon signed-rank test of the
    per-pose differences ||r_p(current)||_K^2 - ||r_p(new)||_K^2 > 0 at alpha / n_candidates

(Bonferroni over the candidates of the step). The significant candidate with the lowest ``H``
is added (``both`` only when it is significantly better than the leg's better single part, by
the same test), and the step repeats until none is significant. On clean data a free map
(6 to 15 more parameters) does a little worse on held-out poses than the rotation it replaces:
the ratio stays near 1. The selected model is then refitted on every pose by Gauss-Newton
(exact rotation updates, three iterations).

A free map is described relative to the transducer's nominal rotation ``R_nom,k`` by its reading
map ``G = M^-1 R_nom`` (reading = ``G`` x true wrench in sensor axes; force and torque apart),
split by the left polar decomposition ``G = S U``, ``U`` orthogonal, ``S`` symmetric positive
definite in the reading's axes. ``U`` is the nearest signed permutation ``Pi`` (48 candidates;
``det < 0``: an odd number of sign flips, or two axes swapped) times a small rotation ``Pi^T U``
(mounting error, rotation vector in deg); the diagonal of ``S`` are the per-axis gains, its
off-diagonal entries the crosstalk. Standard errors: pose-clustered sandwich covariance of the
last Gauss-Newton step (robust to unequal force and torque noise), carried to the derived
quantities by the delta method (numerical Jacobian). A gain or crosstalk is stated when it is
4 se and 0.5 % away from 1 or 0.

Check 2: swing refit per leg (walking recordings)
--------------------------------------------------
While a foot is in the air (``views.walking_views``' detection: fast shaft well outside the
stance range), its reading is offset plus its leg's weight wrench. With the calibration's
offset ``w_o``, weight ``m g`` and CoM curve ``r(phi)`` (all from hanging), ``w~ = w_m - w_o``:

    |f~| = m g,        tau~ = r(phi) x m g u.

A leg that weighs ``dW`` more (less) than it did hanging, with its moment changed, reads

    |f~| - m g - s_perp^2 / (2 m g) = dW + noise,
    tau~ - r(phi) x m g u = kappa (r(phi) x u) + m g (dr x u) + noise,

``dW`` (N) the weight change, from the force norm (no rotation enters it, so a calibration whose
rotations a faulty leg pulled cannot fake it; ``s_perp^2`` the noise variance across ``u``, whose
mean the norm picks up); ``kappa`` (N) the change of the leg's moment along its CoM curve,
``(m g + kappa) r(phi)`` (``kappa = dW`` for mass added at the CoM, larger for mass added farther
out); ``dr`` (m, ft_k) a constant shift of the CoM curve across the mean gravity direction (the
swing data do not determine its component along ``u`` while the body stays level). ``u`` is the
gravity direction in ft_k from the motion capture and the calibrated rotation, turned by the one
rotation that takes its mean onto the mean measured force direction (the calibrated rotation's
error drops out; the per-sample motion-capture direction keeps its small noise). The torque
rows are fitted by least squares weighted by each component's high-frequency noise
(``views.hf_floor``), ``dW`` is the mean; standard errors from a sandwich over blocks of
``block_s`` seconds (serial correlation), never below the per-sample sandwich. The hanging
estimates' own uncertainty adds:

    var(dW) = var_fit + u^T Cov(f_o) u + se(m g)^2,      z_W = dW / sd(dW),   z_kappa likewise,

the torque offsets' se carried into ``kappa`` and ``dr``. A leg is flagged when ``|z_W|`` or
``|z_kappa|`` exceeds the Bonferroni bound over legs and the two statistics (family-wise
``alpha``) and that change exceeds ``min_weight_N``: "leg X weighs dW +- se N more than when it
hung". ``dr`` is reported, not tested: a torque-offset change after hanging looks the same. An
offset change after hanging also reads as a weight change; ``kappa`` (which follows ``r(phi)``)
is what an offset cannot produce. No walking recording, or too few swing samples: no finding,
said so.

:func:`perleg_checks` runs both and returns :class:`PerLegFindings` with plain statements.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.linalg import polar
from scipy.stats import chi2, norm, wilcoxon

from ..core.balance import K_DIAG, features, knorm2, residual
from ..core.calibration import Calibration
from ..core.data import Dataset
from ..core.geometry import rotation_between, rotation_to_rotvec, rotvec_to_rotation, skew, transform_wrench
from ..core.results import ResultsMixin, StackedResults, Summary, fmt_pm
from ..core.robot import Robot
from ..core.solver import identifiability
from .views import LegSeries, walking_views

__all__ = ["ALPHA", "MAX_RATIO", "MIN_WEIGHT_N", "LegMap", "LinearMapCheck", "SwingLegFit", "SwingCheck", "Finding",
           "PerLegFindings", "linear_map_check", "swing_check", "perleg_checks"]

ALPHA = 0.01            # family-wise false-alarm rate of each check (Bonferroni over legs and statistics)
MAX_RATIO = 0.5         # a leg's free map must at least halve the held-out K-norm RSS
MIN_WEIGHT_N = 0.1      # smallest weight (moment) change called a changed leg: ~10 g, 1.6 % of a BigAnt leg
MIN_SWING = 50          # fewest swing samples of a leg for the refit
BLOCK_S = 0.5           # blocks of the sandwich covariance of the swing refit
MIN_POSES = 30          # fewest standing poses for the cross-validated map check
SHARED_LEGS = 3         # a swing finding on at least this many legs (and most of them) is called shared
MOMENT_REL_TOL = 1e-4   # swing moment directions below this relative (scaled) information are not determined

FORCE = ("fx", "fy", "fz")
TORQUE = ("tx", "ty", "tz")
PARTS = ("force", "torque")
_PAIRS = ((0, 1), (0, 2), (1, 2))
_SIGNED_PERMS = [np.diag(s)[list(p)] for p in itertools.permutations(range(3)) for s in itertools.product((1.0, -1.0), repeat=3)]


# ----------------------------------------------------------------------------- check 1: free linear map


def _nearest_signed_permutation(U: np.ndarray) -> np.ndarray:
    """The signed permutation matrix ``Pi`` maximising ``trace(Pi^T U)`` (nearest in Frobenius norm)."""
    return max(_SIGNED_PERMS, key=lambda P: float(np.sum(P * U)))


def _describe_part(A: np.ndarray, R_nom: np.ndarray, Pi: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Derived quantities of one 3x3 map ``A`` (ft -> B): gains (3), crosstalk (3: 01, 02, 12),
    residual rotation vector (3, deg) of the reading map ``G = A^-1 R_nom = S U``; and ``Pi``."""
    G = np.linalg.solve(A, R_nom)
    U, S = polar(G, side="left")     # G = S U
    if Pi is None:
        Pi = _nearest_signed_permutation(U)
    Q = Pi.T @ U
    if np.linalg.det(Q) < 0:          # cannot happen with the nearest Pi of an orthogonal U; guard anyway
        Q = -Q
    vals = np.concatenate([np.diag(S), [S[i, j] for i, j in _PAIRS], np.degrees(rotation_to_rotvec(Q))])
    return vals, Pi


@dataclass(frozen=True)
class LegMap(ResultsMixin):
    """The free linear map of one leg's readings (check 1).

    ``parts`` the parts that are free (``"force"``, ``"torque"``); ``A``, ``B`` (3, 3) the force
    and torque maps ft_k -> B (None: that part kept at a rotation); ``cov_map`` covariance of their
    row-major entries (A's then B's, sandwich); ``R_nominal`` (3, 3) the nominal rotation the
    description refers to; ``perm`` part -> the nearest signed permutation (reading <- true) of
    the reading map; ``values``/``cov`` the 18 derived quantities (force then torque: gains of the
    three axes, crosstalk xy, xz, yz, residual rotation x, y, z in deg; NaN for a part not free)
    and their covariance; ``joint`` whether it was fitted with other flagged legs' maps.
    """

    leg: str
    parts: tuple[str, ...]
    A: np.ndarray | None
    B: np.ndarray | None
    cov_map: np.ndarray
    R_nominal: np.ndarray
    perm: dict
    values: np.ndarray
    cov: np.ndarray
    joint: bool = False

    @property
    def params(self) -> pd.Series:
        names = []
        for part, ax in (("force", FORCE), ("torque", TORQUE)):
            names += [f"{self.leg}.{part}_gain.{a}" for a in ax]
            names += [f"{self.leg}.{part}_crosstalk.{ax[i]}{ax[j][1]}" for i, j in _PAIRS]
            names += [f"{self.leg}.{part}_rotation_deg.{c}" for c in "xyz"]
        return pd.Series(self.values, index=names, name="params")

    def _cov_array(self) -> np.ndarray:
        return np.nan_to_num(self.cov)

    def _bse_array(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))   # NaN where the part is not free

    def improper(self, part: str) -> bool:
        """Whether the part's reading map is improper (``det < 0``: a sign flip or a swap)."""
        return part in self.perm and bool(np.linalg.det(self.perm[part]) < 0)

    def findings(self, z_bound: float = 4.0, min_gain: float = 0.005, min_crosstalk: float = 0.005) -> list[tuple[str, tuple[str, ...]]]:
        """``(phrase, components)`` for what the map shows: permuted / sign-flipped axes, gains and
        crosstalk beyond ``z_bound`` standard errors and the practical sizes ``min_gain``, ``min_crosstalk``."""
        out = []
        se = self._bse_array()
        for part, ax, off in (("force", FORCE, 0), ("torque", TORQUE, 9)):
            if part not in self.parts:
                continue
            Pi = self.perm[part]
            if not np.allclose(Pi, np.eye(3)):
                moved = tuple(ax[i] for i in range(3) if not np.isclose(Pi[i, i], 1.0))
                out.append((_perm_phrase(Pi, ax) + (" (an improper map: det < 0)" if np.linalg.det(Pi) < 0 else ""), moved))
            for i in range(3):
                v, s = self.values[off + i], se[off + i]
                if abs(v - 1.0) > max(z_bound * s, min_gain):
                    out.append((f"{ax[i]} gain {fmt_pm(v, s)} ({100 * (v - 1):+.1f} %, z = {(v - 1) / s:.0f})", (ax[i],)))
            for n, (i, j) in enumerate(_PAIRS):
                v, s = self.values[off + 3 + n], se[off + 3 + n]
                if abs(v) > max(z_bound * s, min_crosstalk):
                    out.append((f"{ax[i]}-{ax[j]} crosstalk {fmt_pm(v, s)} (z = {v / s:.0f})", (ax[i], ax[j])))
        return out

    def describe(self, **kw) -> list[str]:
        """The phrases of :meth:`findings`."""
        return [p for p, _ in self.findings(**kw)]

    def summary(self) -> Summary:
        se = self._bse_array()
        tab = pd.DataFrame({"value ± se": [fmt_pm(v, s) if np.isfinite(v) else "not free" for v, s in zip(self.values, se)]},
                           index=self.params.index)
        facts = [("leg", self.leg), ("free parts", ", ".join(self.parts))]
        facts += [(f"{part} axes (reading <- true)", _perm_phrase(self.perm[part], ax) or "as nominal")
                  for part, ax in (("force", FORCE), ("torque", TORQUE)) if part in self.perm]
        facts.append(("fitted jointly with other legs", str(self.joint)))
        return Summary(f"Free linear map of leg {self.leg}'s readings", facts,
                       [("Reading map G = S U relative to the nominal rotation: gains, crosstalk (S), residual rotation (U)", tab)])


def _perm_phrase(Pi: np.ndarray, ax) -> str:
    """``Pi`` (reading <- true) in words: swapped pairs, sign flips, other permutations."""
    if np.allclose(Pi, np.eye(3)):
        return ""
    src = [int(np.argmax(np.abs(Pi[i]))) for i in range(3)]
    sign = [float(Pi[i, src[i]]) for i in range(3)]
    parts, done = [], set()
    for i in range(3):
        j = src[i]
        if i in done:
            continue
        if j != i and src[j] == i:
            flip = [a for a in (i, j) if sign[a] < 0]
            parts.append(f"{ax[i]} and {ax[j]} swapped" + (f" with {' and '.join(ax[a] for a in flip)} sign-flipped" if flip else ""))
            done |= {i, j}
        elif j == i:
            if sign[i] < 0:
                parts.append(f"{ax[i]} sign-flipped")
            done.add(i)
    rest = [i for i in range(3) if i not in done]
    if rest:
        parts.append(", ".join(f"reading {ax[i]} carries {'-' if sign[i] < 0 else ''}{ax[src[i]]}" for i in rest))
    return "; ".join(parts)


@dataclass(frozen=True)
class LinearMapStep:
    """One forward-selection step: the free parts before it, the candidates ``(leg, part)``
    (``part`` ``"force"``, ``"torque"`` or ``"both"``) with their held-out RSS ratio to the model
    before and one-sided Wilcoxon p-value, the Bonferroni level, and the candidate added (or None)."""

    before: tuple[tuple[str, str], ...]
    candidates: tuple[tuple[str, str], ...]
    ratio: np.ndarray
    p_value: np.ndarray
    level: float
    added: tuple[str, str] | None

    def best(self, leg: str) -> tuple[str, float, float]:
        """``(part, ratio, p)`` of the leg's best candidate at this step (ratio NaN if none)."""
        idx = [i for i, (k, _) in enumerate(self.candidates) if k == leg]
        if not idx:
            return "", np.nan, np.nan
        i = min(idx, key=lambda j: self.ratio[j])
        return self.candidates[i][1], float(self.ratio[i]), float(self.p_value[i])


@dataclass(frozen=True)
class LinearMapCheck(StackedResults):
    """Check 1 over every leg (module docstring).

    ``rss_cal`` the calibration's K-norm RSS over the poses (in-sample for it); ``rss_base`` the
    base's held-out RSS (the calibration refitted to first order on the training poses, plus the
    constant); ``rss_final`` the selected model's; ``steps`` the forward selection; ``selected``
    ``(leg, part)`` in order of selection; ``flagged`` the legs among them; ``maps`` leg ->
    :class:`LegMap` (flagged legs: the final joint fit of their selected parts; the others: both
    parts free, alone, on every pose, for reference); ``note`` why the check did not run, if so.
    """

    legs: tuple[str, ...]
    n_poses: int
    folds: int
    seed: int
    alpha: float
    max_ratio: float
    rss_cal: float = np.nan
    rss_base: float = np.nan
    rss_final: float = np.nan
    steps: tuple[LinearMapStep, ...] = ()
    selected: tuple[tuple[str, str], ...] = ()
    maps: dict = field(default_factory=dict)
    note: str = ""

    @property
    def flagged(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(k for k, _ in self.selected))

    @property
    def ratio(self) -> np.ndarray:
        """Per leg, the best held-out RSS ratio of its candidates at the first step (each leg alone)."""
        return np.array([self.steps[0].best(k)[1] for k in self.legs]) if self.steps else np.full(len(self.legs), np.nan)

    @property
    def p_value(self) -> np.ndarray:
        return np.array([self.steps[0].best(k)[2] for k in self.legs]) if self.steps else np.full(len(self.legs), np.nan)

    def free_parts(self, leg: str) -> tuple[str, ...]:
        return tuple(p for p in PARTS if any(k == leg and q in (p, "both") for k, q in self.selected))

    def _parts(self) -> list:
        return [self.maps[k] for k in self.legs if k in self.maps]

    def table(self) -> pd.DataFrame:
        rows = {}
        for k in self.legs:
            part, ratio, p = self.steps[0].best(k) if self.steps else ("", np.nan, np.nan)
            m = self.maps.get(k)
            rows[k] = {"best map alone": part, "held-out RSS ratio": ratio, "p (Wilcoxon)": f"{p:.2g}",
                       "flagged": ", ".join(self.free_parts(k)),
                       "what the map shows": "; ".join(m.describe()) if (m is not None and k in self.flagged) else ""}
        return pd.DataFrame.from_dict(rows, orient="index")

    def summary(self) -> Summary:
        facts = [("poses, folds, seed", f"{self.n_poses}, {self.folds}, {self.seed}"),
                 ("criterion", f"held-out K-norm RSS ratio < {self.max_ratio:g} and one-sided Wilcoxon p < {self.alpha:g} / candidates"),
                 ("K-norm RSS: calibration (in-sample); base, selected (held-out)",
                  f"{self.rss_cal:.4g}; {self.rss_base:.4g}, {self.rss_final:.4g}"),
                 ("flagged", ", ".join(f"{k} ({p})" for k, p in self.selected) or "none")]
        out = Summary("Per-leg check 1: free linear map of each leg's readings (standing poses)", facts)
        if self.steps:
            out.tables.append(("Each leg's map alone against the calibration (first step)", self.table()))
        if self.note:
            out.notes.append(self.note)
        return out


class _MapProblem:
    """The standing balance with every leg's force and torque maps ``MF_k``, ``MT_k`` (ft_k -> B) and
    positions ``p_k``, linearised at a state (module docstring). Non-reading terms (weights) stay at
    the calibration's values: ``r_p = g_p + sum_k [MF_k f~; MT_k tau~ + p_k x MF_k f~] + c``."""

    def __init__(self, poses, calibration: Calibration, legs: tuple[str, ...], balance: str):
        off, m, R, p = calibration.stacked(legs)
        xi = features(poses.w_m, poses.phi, poses.R_WB, calibration, legs, balance)
        r_cal = residual(xi, R, p, off, m, calibration.mass_kg * calibration.g, balance)
        self.w = poses.w_m - off[None]                                        # (P, K, 6) readings less offsets
        self.g = r_cal - transform_wrench(R[None], p[None], self.w).sum(axis=1)
        self.z = poses.R_WB[:, 2, :]                                          # up in B
        self.R, self.p0 = R, p
        self.P, self.K = len(r_cal), len(legs)
        self.sqrtK = np.sqrt(K_DIAG)

    def residual(self, MF: np.ndarray, MT: np.ndarray, p: np.ndarray) -> np.ndarray:
        F = np.einsum("kij,pkj->pki", MF, self.w[:, :, :3])
        T = np.einsum("kij,pkj->pki", MT, self.w[:, :, 3:]) + np.cross(p[None], F)
        return self.g + np.concatenate([F.sum(axis=1), T.sum(axis=1)], axis=1)

    def design(self, MF: np.ndarray, MT: np.ndarray, p: np.ndarray, free: dict) -> tuple[np.ndarray, list]:
        """Design (P, 6, n) of the increments at the state and its blocks ``(k, kind, slice)``:
        ``A``/``B`` 9 free entries, ``dF``/``dT``/``d`` 3 rotation increments (left, B axes) of a part
        kept a rotation (``d``: both parts, shared), ``dp`` 3 position increments, ``c`` the constant,
        ``W`` the body weight's increment."""
        P = self.P
        cols, blocks, n = [], [], 0

        def add(k, kind, X):
            nonlocal n
            cols.append(X)
            blocks.append((k, kind, slice(n, n + X.shape[2])))
            n += X.shape[2]

        for k in range(self.K):
            f, t = self.w[:, k, :3], self.w[:, k, 3:]
            Fk = f @ MF[k].T
            Tk = t @ MT[k].T
            Sp = skew(p[k])
            parts = free.get(k, set())
            if "force" in parts:
                X = np.zeros((P, 6, 9))
                for i in range(3):
                    for j in range(3):
                        X[:, i, 3 * i + j] = f[:, j]
                        X[:, 3:, 3 * i + j] = Sp[:, i][None, :] * f[:, j : j + 1]
                add(k, "A", X)
            if "torque" in parts:
                X = np.zeros((P, 6, 9))
                for i in range(3):
                    X[:, 3 + i, 3 * i : 3 * i + 3] = t
                add(k, "B", X)
            XF = np.concatenate([-skew(Fk), -Sp[None] @ skew(Fk)], axis=1)        # d/d delta of the force part
            XT = np.concatenate([np.zeros((P, 3, 3)), -skew(Tk)], axis=1)          # d/d delta of the torque part
            if not parts:
                add(k, "d", XF + XT)
            elif parts == {"force"}:
                add(k, "dT", XT)
            elif parts == {"torque"}:
                add(k, "dF", XF)
            add(k, "dp", np.concatenate([np.zeros((P, 3, 3)), -skew(Fk)], axis=1))
        add(-1, "c", np.broadcast_to(np.eye(6), (P, 6, 6)))
        add(-1, "W", np.concatenate([-self.z, np.zeros((P, 3))], axis=1)[:, :, None])
        return np.concatenate(cols, axis=2), blocks

    def fit(self, r0: np.ndarray, X: np.ndarray, idx: np.ndarray) -> np.ndarray:
        w = self.sqrtK
        Xw = (X[idx] * w[None, :, None]).reshape(-1, X.shape[2])
        yw = -(r0[idx] * w).reshape(-1)
        scale = np.linalg.norm(Xw, axis=0)
        scale = np.where(scale > 0, scale, 1.0)
        theta, *_ = np.linalg.lstsq(Xw / scale, yw, rcond=1e-10)
        return theta / scale

    def heldout(self, free: dict, fold: np.ndarray, folds: int) -> np.ndarray:
        """Held-out K-norm residual of every pose (P,) of the model linearised at the calibration."""
        MF = MT = self.R
        r0 = self.residual(MF, MT, self.p0) * self.sqrtK
        X = self.design(MF, MT, self.p0, free)[0] * self.sqrtK[None, :, None]
        n = X.shape[2]
        Xs = [X[fold == f].reshape(-1, n) for f in range(folds)]
        Hf = np.stack([x.T @ x for x in Xs])
        bf = np.stack([x.T @ r0[fold == f].reshape(-1) for f, x in enumerate(Xs)])
        H, b = Hf.sum(axis=0), bf.sum(axis=0)
        out = np.empty(self.P)
        for f in range(folds):
            test = fold == f
            theta = -_solve_psd(H - Hf[f], b - bf[f])
            out[test] = np.sum((r0[test] + X[test] @ theta) ** 2, axis=1)
        return out

    def final_fit(self, free: dict, iterations: int = 3):
        """Gauss-Newton on every pose from the calibration: ``(MF, MT, p, blocks, cov)``, the covariance
        (pose-clustered sandwich) of the last linearisation's increments."""
        MF, MT, p = self.R.copy(), self.R.copy(), self.p0.copy()
        for _ in range(iterations):
            r0 = self.residual(MF, MT, p)
            X, blocks = self.design(MF, MT, p, free)
            theta = self.fit(r0, X, np.ones(self.P, bool))
            MF, MT, p = MF.copy(), MT.copy(), p.copy()
            for k, kind, sl in blocks:
                d = theta[sl]
                if kind == "A":
                    MF[k] += d.reshape(3, 3)
                elif kind == "B":
                    MT[k] += d.reshape(3, 3)
                elif kind in ("d", "dF", "dT"):
                    Q = rotvec_to_rotation(d)
                    if kind in ("d", "dF"):
                        MF[k] = Q @ MF[k]
                    if kind in ("d", "dT"):
                        MT[k] = Q @ MT[k]
                elif kind == "dp":
                    p[k] += d
        r0 = self.residual(MF, MT, p)
        X, blocks = self.design(MF, MT, p, free)
        theta = self.fit(r0, X, np.ones(self.P, bool))
        r = r0 + X @ theta
        Xw = (X * K_DIAG[None, :, None]).reshape(-1, X.shape[2])
        H = Xw.T @ X.reshape(-1, X.shape[2])
        gp = np.einsum("pci,c,pc->pi", X, K_DIAG, r)
        n, d = 6 * self.P, X.shape[2]
        s = np.sqrt(np.clip(np.diag(H), 1e-300, None))
        Hi = np.linalg.pinv(H / np.outer(s, s), rcond=1e-12) / np.outer(s, s)
        cov = Hi @ (gp.T @ gp) @ Hi * n / max(n - d, 1)
        return MF, MT, p, blocks, cov


def _solve_psd(H: np.ndarray, b: np.ndarray, rel_tol: float = 1e-12) -> np.ndarray:
    """Minimum-norm solution of ``H x = b`` for a positive semi-definite ``H`` (scaled to unit
    diagonal, eigen-directions below ``rel_tol`` of the largest dropped)."""
    s = np.sqrt(np.clip(np.diag(H), 0.0, None))
    s = np.where(s > 0, s, 1.0)
    lam, V = np.linalg.eigh(H / np.outer(s, s))
    ok = lam > rel_tol * lam.max()
    return (V[:, ok] @ ((V[:, ok].T @ (b / s)) / lam[ok])) / s


def _parts_of(selected) -> dict:
    free: dict = {}
    for k, part in selected:
        free.setdefault(k, set()).update(PARTS if part == "both" else (part,))
    return free


def linear_map_check(poses, calibration: Calibration, robot: Robot, *, balance: str | None = None, folds: int,
                     seed: int, alpha: float = ALPHA, max_ratio: float = MAX_RATIO) -> LinearMapCheck:
    """Check 1 (module docstring) on standing ``poses`` (``standing.Poses``, legs in robot order).

    ``balance``: ``"exact"`` or ``"report"`` (None: the calibration's ``meta['balance']``, else exact).
    """
    legs = tuple(robot.legs)
    K = len(legs)
    need = max(MIN_POSES, 2 * folds)
    if poses is None or poses.n < need:
        n = 0 if poses is None else poses.n
        note = f"only {n} standing poses: too few for the cross-validated map check (need {need})"
        return LinearMapCheck(n_poses=n, note=note, legs=legs, folds=folds, seed=seed, alpha=alpha, max_ratio=max_ratio)
    if tuple(poses.legs) != legs:
        raise ValueError(f"linear_map_check: pose legs {poses.legs} differ from the robot's {legs}")
    balance = balance or (calibration.meta or {}).get("balance") or "exact"
    prob = _MapProblem(poses, calibration, legs, balance)
    P = prob.P
    fold = np.empty(P, int)
    fold[np.random.default_rng(seed).permutation(P)] = np.arange(P) % folds
    rss_cal = float(knorm2(prob.residual(prob.R, prob.R, prob.p0)).sum())
    current = prob.heldout({}, fold, folds)
    rss_base = float(current.sum())
    selected: list[tuple[int, str]] = []
    steps = []

    def test(h_new, h_old):
        d = h_old - h_new
        return h_new.sum() / h_old.sum(), (float(wilcoxon(d, alternative="greater").pvalue) if np.any(d != 0) else 1.0)

    while True:
        free = _parts_of(selected)
        cands = [(k, part) for k in range(K) for part in ("force", "torque", "both")
                 if not set(PARTS if part == "both" else (part,)) <= free.get(k, set())
                 and not (part == "both" and free.get(k))]
        if not cands:
            break
        level = alpha / len(cands)
        ratio, pval, held = np.full(len(cands), np.nan), np.full(len(cands), np.nan), []
        for i, (k, part) in enumerate(cands):
            h = prob.heldout(_parts_of(selected + [(k, part)]), fold, folds)
            ratio[i], pval[i] = test(h, current)
            held.append(h)
        ok = [i for i in range(len(cands)) if ratio[i] < max_ratio and pval[i] < level]
        pick = None
        if ok:
            pick = min(ok, key=lambda i: ratio[i])
            k = cands[pick][0]
            if cands[pick][1] == "both":  # the simpler single part unless both are significantly better
                singles = [i for i in ok if cands[i][0] == k and cands[i][1] != "both"]
                if singles:
                    j = min(singles, key=lambda i: ratio[i])
                    if test(held[pick], held[j])[1] >= level:
                        pick = j
        steps.append(LinearMapStep(tuple((legs[k], q) for k, q in selected), tuple((legs[k], q) for k, q in cands), ratio, pval, level,
                                   None if pick is None else (legs[cands[pick][0]], cands[pick][1])))
        if pick is None:
            break
        selected.append(cands[pick])
        current = held[pick]
    R_nom = robot.nominal_rotations()
    maps = {}
    flagged = list(dict.fromkeys(k for k, _ in selected))
    if selected:
        free = _parts_of(selected)
        MF, MT, _, blocks, cov = prob.final_fit(free)
        for k in flagged:
            maps[legs[k]] = _leg_map(legs[k], free[k], MF[k], MT[k], blocks, cov, k, R_nom[k], joint=len(flagged) > 1)
    for k in range(K):
        if k not in flagged:
            MF, MT, _, blocks, cov = prob.final_fit({k: set(PARTS)}, iterations=1)
            maps[legs[k]] = _leg_map(legs[k], set(PARTS), MF[k], MT[k], blocks, cov, k, R_nom[k], joint=False)
    return LinearMapCheck(n_poses=P, rss_cal=rss_cal, rss_base=rss_base, rss_final=float(current.sum()), steps=tuple(steps),
                          selected=tuple((legs[k], q) for k, q in selected), maps=maps,
                          legs=legs, folds=folds, seed=seed, alpha=alpha, max_ratio=max_ratio)


def _leg_map(leg: str, parts: set, MF: np.ndarray, MT: np.ndarray, blocks, cov: np.ndarray, k: int, R_nom: np.ndarray,
             joint: bool) -> LegMap:
    idx = {kind: sl for kk, kind, sl in blocks if kk == k}
    vals = np.full(18, np.nan)
    C = np.full((18, 18), np.nan)
    perm = {}
    sl_all, J_parts = [], []
    for part, M, kind, off in (("force", MF, "A", 0), ("torque", MT, "B", 9)):
        if part not in parts:
            continue
        v, Pi = _describe_part(M, R_nom)
        vals[off : off + 9] = v
        perm[part] = Pi
        # delta method: the derived quantities of a part depend on its own 9 entries only
        J = np.zeros((9, 9))
        h = 1e-6 * max(np.abs(M).max(), 1e-9)
        for e in range(9):
            dM = np.zeros(9)
            dM[e] = h
            vp, _ = _describe_part(M + dM.reshape(3, 3), R_nom, Pi)
            vm, _ = _describe_part(M - dM.reshape(3, 3), R_nom, Pi)
            J[:, e] = (vp - vm) / (2 * h)
        sl_all.append((off, idx[kind]))
        J_parts.append(J)
    for (o1, s1), J1 in zip(sl_all, J_parts):
        for (o2, s2), J2 in zip(sl_all, J_parts):
            C[o1 : o1 + 9, o2 : o2 + 9] = J1 @ cov[s1, s2] @ J2.T
    cm = np.concatenate([np.arange(s.start, s.stop) for _, s in sl_all])
    return LegMap(leg, tuple(p for p in PARTS if p in parts), MF if "force" in parts else None, MT if "torque" in parts else None,
                  cov[np.ix_(cm, cm)], R_nom, perm, vals, C, joint)


# ----------------------------------------------------------------------------- check 2: swing refit


@dataclass(frozen=True)
class SwingLegFit(ResultsMixin):
    """One leg's swing refit (check 2).

    ``params``: ``dW`` (N) weight change, ``kappa`` (N) moment change along the CoM curve,
    ``dr_a``, ``dr_b`` (m) the CoM shift across the mean gravity direction ``u_mean`` (ft_k),
    and the same shift in ft_k axes ``dr_x..z`` (derived; its component along ``u_mean`` is 0 by
    construction). ``cov_fit`` the block-sandwich covariance of the fit alone; ``cov`` with the
    hanging estimates' uncertainty added; ``determined`` (7,) the parameters the swing data
    determine; ``z_weight`` ``dW / sd``; ``chi2_moment``/``dof_moment``/``p_moment`` the Wald
    test of ``(kappa, dr_a, dr_b)``; ``n`` swing samples; ``hanging_weight_N``/``_se_N``;
    ``rms_before``/``rms_after`` (4,): |f| - mg and the three torques, before and after the refit.
    """

    leg: str
    theta: np.ndarray
    cov_fit: np.ndarray
    cov: np.ndarray
    determined: np.ndarray
    u_mean: np.ndarray
    n: int
    z_weight: float
    chi2_moment: float
    dof_moment: int
    p_weight: float
    p_moment: float
    hanging_weight_N: float
    hanging_weight_se_N: float
    rms_before: np.ndarray
    rms_after: np.ndarray

    NAMES = ("dW_N", "kappa_N", "dr_a_m", "dr_b_m", "dr_x_m", "dr_y_m", "dr_z_m")

    @property
    def params(self) -> pd.Series:
        return pd.Series(self.theta, index=[f"{self.leg}.{n}" for n in self.NAMES], name="params")

    def _cov_array(self) -> np.ndarray:
        return self.cov

    def _bse_array(self) -> np.ndarray:
        se = np.sqrt(np.clip(np.diag(self.cov), 0.0, None))
        return np.where(self.determined, se, np.inf)

    @property
    def weight_se_N(self) -> float:
        return float(self._bse_array()[0])

    @property
    def z_moment(self) -> float:
        """``kappa / se``: the moment change along the CoM curve in standard errors (0 if not determined)."""
        se = self._bse_array()[1]
        return float(self.theta[1] / se) if np.isfinite(se) and se > 0 else 0.0

    def summary(self) -> Summary:
        se = self._bse_array()
        tab = pd.DataFrame({"value ± se": [fmt_pm(v, s) for v, s in zip(self.theta, se)]}, index=self.params.index)
        facts = [("swing samples", str(self.n)), ("hanging weight [N]", fmt_pm(self.hanging_weight_N, self.hanging_weight_se_N)),
                 ("weight change z", f"{self.z_weight:.2f}"), ("moment change chi2 (dof)", f"{self.chi2_moment:.1f} ({self.dof_moment})")]
        return Summary(f"Swing refit of leg {self.leg}", facts, [("Change since hanging", tab)])


@dataclass(frozen=True)
class SwingCheck(StackedResults):
    """Check 2 over every leg: ``fits`` leg -> :class:`SwingLegFit` (legs with enough swing samples),
    ``flagged`` legs, ``z_bound`` the Bonferroni bound of the weight and moment z (two statistics
    per leg, family-wise ``alpha``), ``min_weight_N`` the smallest change called,
    ``notes`` (no walking recordings, too few samples, ...)."""

    legs: tuple[str, ...]
    alpha: float
    z_bound: float
    min_weight_N: float
    fits: dict = field(default_factory=dict)
    flagged: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    def _parts(self) -> list:
        return [self.fits[k] for k in self.legs if k in self.fits]

    def table(self) -> pd.DataFrame:
        rows = {}
        for k in self.legs:
            f = self.fits.get(k)
            if f is None:
                rows[k] = {"n": 0, "dW [N]": "n/a", "z": np.nan, "kappa [N]": "n/a", "z kappa": np.nan, "flagged": ""}
                continue
            se = f._bse_array()
            rows[k] = {"n": f.n, "dW [N]": fmt_pm(f.theta[0], se[0]), "z": f.z_weight, "kappa [N]": fmt_pm(f.theta[1], se[1]),
                       "z kappa": f.z_moment, "flagged": "yes" if k in self.flagged else ""}
        return pd.DataFrame.from_dict(rows, orient="index")

    def summary(self) -> Summary:
        facts = [("criterion", f"|z| of the weight change dW or of the moment change kappa > {self.z_bound:.2f} (family-wise "
                               f"{self.alpha:g}) and that change > {self.min_weight_N:g} N"),
                 ("flagged legs", ", ".join(self.flagged) or "none")]
        out = Summary("Per-leg check 2: each leg's weight and CoM refit on its swing phases (walking)", facts,
                      [("Change since hanging", self.table())] if self.fits else [])
        out.notes += list(self.notes)
        return out


def _blocks(t: np.ndarray, rec: np.ndarray, block_s: float) -> np.ndarray:
    """Block labels: recording, then contiguous stretches of ``block_s`` seconds (a gap starts a new one)."""
    lab = np.zeros(len(t), int)
    cur, start = 0, None
    for i in range(len(t)):
        if i == 0 or rec[i] != rec[i - 1] or t[i] - t[i - 1] > 0.1 or t[i] - start >= block_s:
            cur += i > 0
            start = t[i]
        lab[i] = cur
    return lab


def _swing_leg(l, cal_leg, block_s: float, floor: np.ndarray) -> SwingLegFit:
    """The swing refit of one leg (module docstring): weight from the force norm, moment from the torques."""
    N = len(l.t)
    mg = float(l.mg)
    w = l.e + l.applied                                   # w_m - w_o, ft_k
    fn = np.linalg.norm(w[:, :3], axis=1)                # |f~|: the weight, whatever the frame
    u = l.f / mg if mg != 0 else l.f                     # gravity direction in ft_k: motion capture, calibrated R_k ...
    f_dir = np.mean(w[:, :3] / np.where(fn > 0, fn, 1.0)[:, None], axis=0)
    u = u @ rotation_between(u.mean(axis=0), f_dir).T    # ... turned onto the mean measured force direction
    sig = np.where(np.isfinite(floor) & (floor > 0), floor, np.sqrt(np.mean(l.e**2, axis=0)) + 1e-12)
    # |f| = mg + n_u + |n_perp|^2 / (2 mg): remove the noise's mean contribution across u
    u_bar = u.mean(axis=0)
    u_bar /= np.linalg.norm(u_bar)
    s_perp2 = float(np.sum(sig[:3] ** 2) - (u_bar**2) @ sig[:3] ** 2)
    y_w = fn - mg - s_perp2 / (2 * max(mg, 1e-9))
    # moment: tau~ - r x (mg u) = kappa (r x u) + mg (dr x u), dr in the plane across mean u
    E = np.linalg.svd(u_bar[None, :])[2][1:]              # (2, 3) orthonormal basis across u_bar
    eps = w[:, 3:] - np.cross(l.r, mg * u)
    X = np.zeros((N, 3, 3))
    X[:, :, 0] = np.cross(l.r, u)
    for a in range(2):
        X[:, :, 1 + a] = mg * np.cross(E[a][None, :], u)
    Wt = 1.0 / sig[3:] ** 2
    H = np.einsum("nci,c,ncj->ij", X, Wt, X)
    ident = identifiability(H, MOMENT_REL_TOL)
    Hi = ident.pinv()
    beta = Hi @ np.einsum("nci,c,nc->i", X, Wt, eps)
    r_t = eps - X @ beta
    dW = float(np.mean(y_w))
    r_f = y_w - dW
    # sandwich over blocks of block_s seconds (serial correlation), both parts together
    lab = _blocks(l.t, l.rec, block_s)
    g = np.concatenate([(r_f / N)[:, None], np.einsum("ij,ncj,c,nc->ni", Hi, X, Wt, r_t)], axis=1)
    G = np.zeros((lab.max() + 1, 4))
    np.add.at(G, lab, g)
    nb = G.shape[0]
    cov_fit = (G.T @ G) * (nb / max(nb - 1, 1))
    cov_hc = (g.T @ g) * (N / max(N - 4, 1))       # per sample: the floor when a few blocks happen to agree
    inflate = np.sqrt(np.maximum(1.0, np.diag(cov_hc) / np.where(np.diag(cov_fit) > 0, np.diag(cov_fit), np.inf)))
    cov_fit = cov_fit * np.outer(inflate, inflate)
    # the hanging estimates' uncertainty: force offset along u and the leg weight -> dW;
    # torque offset -> the moment terms (an offset error is a constant residual)
    off_se = np.asarray(cal_leg.offset_se, float) if cal_leg.offset_se is not None else np.zeros(6)
    off_se = np.where(np.isfinite(off_se), off_se, 0.0)
    wse = cal_leg.leg_weight_se_N
    wse = float(wse) if wse is not None and np.isfinite(wse) else 0.0
    D = np.zeros((4, 6))
    D[0, :3] = -u_bar
    D[1:, 3:] = -Hi @ np.einsum("nci,c->ic", X, Wt)
    cov = cov_fit + D @ np.diag(off_se**2) @ D.T
    cov[0, 0] += wse**2
    theta = np.concatenate([[dW], beta, E.T @ beta[1:]])   # dW, kappa, dr (2 across u), dr in ft_k (3)
    J = np.zeros((7, 4))
    J[:4, :4] = np.eye(4)
    J[4:, 2:] = E.T
    cov = J @ cov @ J.T
    cov_fit = J @ cov_fit @ J.T
    det = np.ones(7, bool)
    for v, _ in ident.undetermined_directions():
        bad = np.abs(v / np.linalg.norm(v)) >= 0.05
        det[1:4] &= ~bad
    det[4:] = det[2] and det[3]
    sd_w = np.sqrt(cov[0, 0])
    z = float(dW / sd_w) if sd_w > 0 else np.nan
    idx = [i for i in (1, 2, 3) if det[i]]
    chi = float(theta[idx] @ np.linalg.pinv(cov[np.ix_(idx, idx)], rcond=1e-12) @ theta[idx]) if idx else 0.0
    rms_before = np.sqrt(np.mean(np.concatenate([(fn - mg)[:, None], eps], axis=1) ** 2, axis=0))
    rms_after = np.sqrt(np.mean(np.concatenate([r_f[:, None], r_t], axis=1) ** 2, axis=0))
    return SwingLegFit(l.leg, theta, cov_fit, cov, det, u_bar, N, z, chi, len(idx), float(2 * norm.sf(abs(z))),
                       float(chi2.sf(chi, len(idx))) if idx else 1.0, mg, wse, rms_before, rms_after)


def swing_check(dataset: Dataset, calibration: Calibration, robot: Robot, *, alpha: float = ALPHA,
                min_weight_N: float = MIN_WEIGHT_N, min_samples: int = MIN_SWING, block_s: float = BLOCK_S,
                swing: LegSeries | None = None) -> SwingCheck:
    """Check 2 (module docstring) on the walking recordings of ``dataset``.

    ``swing``: the walking swing view (``views.walking_views``) when the caller has it already.
    """
    legs = tuple(robot.legs)
    K = len(legs)
    z_bound = float(norm.isf(alpha / (2 * 2 * K)))    # two-sided, 2 statistics per leg
    if swing is None:
        if not dataset.walking:
            return SwingCheck(notes=("no walking recordings: the legs' weights were not refitted on swing phases",), legs=legs, alpha=alpha, z_bound=z_bound, min_weight_N=min_weight_N)
        swing, _ = walking_views(dataset.walking, calibration, robot, 0.0)
    if swing is None:
        return SwingCheck(notes=("no swing phases found in the walking recordings (orientation missing or feet never in the air)",),
                          legs=legs, alpha=alpha, z_bound=z_bound, min_weight_N=min_weight_N)
    fits, notes = {}, []
    have = {l.leg: l for l in swing.legs}
    for k in legs:
        l = have.get(k)
        n = 0 if l is None else len(l.t)
        if l is None or n < min_samples:
            notes.append(f"leg {k}: {n} swing samples (< {min_samples}); its weight was not refitted")
            continue
        fits[k] = _swing_leg(l, calibration.legs[k], block_s, swing.floor[l.k])
    flagged = []
    for k, f in fits.items():
        weight = abs(f.z_weight) > z_bound and abs(f.theta[0]) > min_weight_N
        moment = abs(f.z_moment) > z_bound and abs(f.theta[1]) > min_weight_N
        if weight or moment:
            flagged.append(k)
    return SwingCheck(fits=fits, flagged=tuple(flagged), notes=tuple(notes), legs=legs, alpha=alpha, z_bound=z_bound, min_weight_N=min_weight_N)


# ----------------------------------------------------------------------------- both checks


@dataclass(frozen=True)
class Finding:
    """One per-leg finding: ``leg``, ``kind`` (``"linear_map"`` or ``"swing"``), ``components`` it lies in,
    ``statement`` in plain words, ``size`` (the held-out RSS ratio, or the weight / moment change in N),
    ``z``; ``shared``: the same kind of finding on most legs at once (a common cause is likelier
    than each leg having changed: an offset drift, the legs' swing dynamics)."""

    leg: str
    kind: str
    components: tuple[str, ...]
    statement: str
    size: float
    z: float
    shared: bool = False


@dataclass(frozen=True)
class PerLegFindings:
    """Both per-leg checks: ``linear_map`` (:class:`LinearMapCheck`), ``swing`` (:class:`SwingCheck`),
    ``findings`` (flagged legs, linear map first), ``statements`` (plain text, one a finding,
    then the checks' notes)."""

    linear_map: LinearMapCheck
    swing: SwingCheck
    findings: tuple[Finding, ...]
    statements: tuple[str, ...]

    @property
    def legs(self) -> tuple[str, ...]:
        """Legs with a finding, in order of first mention."""
        return tuple(dict.fromkeys(f.leg for f in self.findings))

    @property
    def clean(self) -> bool:
        return not self.findings

    def summary(self) -> Summary:
        out = Summary("Per-leg checks (no effect library)", [("legs with a finding", ", ".join(self.legs) or "none")])
        for s in (self.linear_map.summary(), self.swing.summary()):
            out.facts += [(f"[{s.title.split(':')[0]}] {k}", v) for k, v in s.facts]
            out.tables += s.tables
            out.notes += s.notes
        out.notes = list(self.statements) + out.notes
        return out


def _findings(lm: LinearMapCheck, sw: SwingCheck) -> tuple[list[Finding], list[str]]:
    out, notes = [], []
    for k in lm.flagged:
        m = lm.maps[k]
        st = [s for s in lm.steps if s.added is not None and s.added[0] == k]
        i = st[0].candidates.index(st[0].added)
        ratio = float(np.prod([s.ratio[s.candidates.index(s.added)] for s in st]))
        p = float(st[0].p_value[i])
        found = m.findings()
        comp = tuple(c for c in FORCE + TORQUE if any(c in cs for _, cs in found))
        what = "; ".join(ph for ph, _ in found) if found else "no single axis, gain or crosstalk stands out (a general distortion)"
        s = (f"Leg {k}: a free linear map of its {' and '.join(m.parts)} readings brings the held-out standing residual to "
             f"{100 * ratio:.1f} % of what the calibration leaves (Wilcoxon p = {p:.2g}); its readings show: {what}.")
        out.append(Finding(k, "linear_map", comp or (FORCE if "force" in m.parts else ()) + (TORQUE if "torque" in m.parts else ()),
                           s, ratio, float(norm.isf(max(p, 1e-300)))))
    for k in sw.flagged:
        f = sw.fits[k]
        se = f._bse_array()
        weight = abs(f.z_weight) > sw.z_bound and abs(f.theta[0]) > sw.min_weight_N
        moment = abs(f.z_moment) > sw.z_bound and abs(f.theta[1]) > sw.min_weight_N
        hung = f"hanging {fmt_pm(f.hanging_weight_N, f.hanging_weight_se_N)} N"
        if weight:
            s = (f"Leg {k} weighs {fmt_pm(abs(f.theta[0]), se[0])} N {'more' if f.theta[0] >= 0 else 'less'} than when it hung "
                 f"(swing phases, z = {f.z_weight:.1f}; {hung})")
            if moment:
                s += f"; its moment about the hip changed by {fmt_pm(f.theta[1], se[1])} N along its CoM curve (z = {f.z_moment:.1f})"
        else:
            s = (f"Leg {k}'s moment about the hip changed by {fmt_pm(f.theta[1], se[1])} N along its CoM curve since it hung "
                 f"(swing phases, z = {f.z_moment:.1f}), its weight did not ({fmt_pm(f.theta[0], se[0])} N; {hung})")
        if k in lm.flagged:
            s += ", as its distorted readings (the linear-map finding) would show."
        else:
            s += ": the leg changed after it hung" + ("" if moment else " (or its force offset did)") + "."
        comp = (FORCE if weight else ()) + (TORQUE if moment else ())
        out.append(Finding(k, "swing", comp, s, float(f.theta[0] if weight else f.theta[1]), float(f.z_weight if weight else f.z_moment)))
    sw_found = [f for f in out if f.kind == "swing" and f.leg not in lm.flagged]
    if len(sw_found) >= SHARED_LEGS and len(sw_found) > len(sw.fits) / 2:
        weight_only = all(not set(f.components) & set(TORQUE) for f in sw_found)
        notes.append(f"{len(sw_found)} of {len(sw.fits)} legs differ from their hanging estimates on their swing phases at once: "
                     + ("a force-offset drift since hanging" if weight_only else "something common to the legs (their swing dynamics, "
                        "an offset drift)") + " is likelier than each leg having changed.")
        out = [Finding(f.leg, f.kind, f.components, f.statement, f.size, f.z, True) if f in sw_found else f for f in out]
    if lm.note:
        notes.append(lm.note)
    notes += list(sw.notes)
    return out, notes


def perleg_checks(dataset: Dataset, calibration: Calibration, poses, robot: Robot, *, folds: int, seed: int,
                  balance: str | None = None, alpha: float = ALPHA, swing: LegSeries | None = None) -> PerLegFindings:
    """Run both per-leg checks (module docstring) and state the findings.

    ``dataset``: its walking recordings feed check 2; ``calibration``: the finished calibration
    (offsets, leg weights and CoM curves from hanging, rotations and positions from standing);
    ``poses``: the standing :class:`~ftcal_nlp.estimate.standing.Poses` (None: check 1 skipped);
    ``folds``/``seed``: the cross-validation of check 1; ``alpha``: family-wise level of each check;
    ``swing``: an already computed walking swing view (``views.walking_views``), optional.
    """
    lm = linear_map_check(poses, calibration, robot, balance=balance, folds=folds, seed=seed, alpha=alpha)
    sw = swing_check(dataset, calibration, robot, alpha=alpha, swing=swing)
    found, notes = _findings(lm, sw)
    statements = [f.statement for f in found]
    if not found:
        statements.append("Per-leg checks: no leg's readings need more than the calibration (free linear map on the standing poses"
                          + (", weight and CoM on the swing phases" if sw.fits else "") + ").")
    return PerLegFindings(lm, sw, tuple(found), tuple(statements + notes))
