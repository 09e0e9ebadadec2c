"""An effect's correction for ``correct``: its standing face evaluated on recorded samples.

A calibration written with the diagnosis' named effect carries in ``meta["effect"]``
(the *block*) the effect's standing-face parameters ``eta`` (the scaled units of
``Effect.standing_params``), their covariance ``eta_cov``, the hanging-face
parameters, ``t_ref_s`` and the design rotations. A sensor effect corrects each
sample by what its standing face does to one transducer's readings and to the
measured orientation (eq. (A) of :mod:`.faces`):

    c_k = c_k(w_k; eta)          corrected readings, per leg (the previous pose is the sample itself)
    R_WB' = R_WB Z(eta)^T        so that the up vector R_WB'^T e_z = Z(eta) z

with the covariance ``J_k Sigma_eta J_k^T``, ``J_k = d c_k / d eta`` (first order). The
same CasADi expressions the diagnosis fitted are evaluated over all samples at once,
in blocks of ``CHUNK`` samples (the standing features are a few hundred columns per
sample). A unit whose correction is something else (an offset drift's rates, a body
effect's "nothing per foot") overrides ``Effect.correct``.

Several effects fitted together (``combined.Combined``, a block with ``members``): each member's block
(:func:`member_block`) is a single effect's, its ``eta`` the member's slice of the joint one; the members whose
correction is their standing face (``unit.corrects_by_face``) are evaluated together as one face, so that the
covariance ``J Sigma_eta J^T`` takes the joint ``eta_cov`` with its cross-member terms (``Combined.correct``).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..geometry import remove_yaw
from ..errors import DataFormatError
from .faces import AugContext, StandingData, pose_symbols

CHUNK = 4096        # samples per block of the effect's correction


def correct_by_face(effect, cal, block: dict, ctx: AugContext, w: np.ndarray, phi: np.ndarray, R_WB: np.ndarray,
                    t_h: np.ndarray, *, with_cov: bool = True, source: str = "calibration"):
    """``(w', R_WB', cov)``: readings (N, K, 6) and orientations (N, 3, 3) corrected by ``effect``'s standing face
    with the block's ``eta``, and the covariance (N, K, 6, 6) of the corrected readings (None without ``eta_cov``
    or ``with_cov``). ``t_h`` (N,) hours since ``t_ref_s``."""
    K, N = ctx.K, len(t_h)
    eta = face_eta(effect, ctx, block, source)
    m = len(eta)
    C = face_eta_cov(block, m, source) if with_cov else None
    und = face_undetermined(block, m, source) if C is not None else None
    d, pose = pose_symbols(K)
    e = ca.SX.sym("eta", m)
    c, zmap, _ = effect.standing(e, pose, ctx)
    Z = zmap if zmap is not None else ca.SX.eye(3)
    outs = [ca.vertcat(*c), ca.reshape(Z, 9, 1)] + ([ca.jacobian(ca.vertcat(*c), e)] if C is not None else [])
    fn = ca.Function("effect", [d, e], outs)
    w_new, R_new = np.empty_like(w, dtype=float), np.empty_like(R_WB, dtype=float)
    cov = np.zeros((N, K, 6, 6)) if C is not None else None
    for a in range(0, N, CHUNK):
        s = slice(a, min(N, a + CHUNK))
        n = s.stop - s.start
        res = fn(sample_features(cal, ctx, w[s], phi[s], R_WB[s], t_h[s]).T, eta)
        w_new[s] = np.asarray(res[0], float).T.reshape(n, K, 6)
        Zs = np.asarray(res[1], float).T.reshape(n, 3, 3).transpose(0, 2, 1)   # columns of Z were stacked (CasADi is column-major)
        R_new[s] = np.einsum("nij,nkj->nik", R_WB[s], Zs)
        if cov is not None:
            J = np.asarray(res[2], float).reshape(6 * K, n, m).transpose(1, 0, 2).reshape(n, K, 6, m)   # samples side by side
            cov[s] = np.einsum("nkam,mq,nkbq->nkab", J, C, J)
            if und is not None:   # a component an undetermined parameter moves has no finite variance
                touched = np.abs(J[..., und]).max(-1) > 0
                ii = np.arange(6)
                diag = cov[s][:, :, ii, ii]
                diag[touched] = np.inf
                cov[s][:, :, ii, ii] = diag
    return w_new, R_new, cov


def face_eta(effect, ctx: AugContext, block: dict, source: str) -> np.ndarray:
    """The standing face's parameters from ``meta.effect.eta`` (as many as the face has)."""
    block_p = effect.standing_params(ctx)
    m = block_p.m if block_p is not None else 0
    eta = np.asarray(block.get("eta", []), float)[:m]
    if len(eta) != m:
        raise DataFormatError(f"{source}: meta.effect.eta has {len(eta)} values, {effect.name} needs {m}")
    return eta


def face_eta_cov(block: dict, m: int, source: str) -> np.ndarray | None:
    """The covariance of the face's ``m`` parameters from ``meta.effect.eta_cov`` (None: not stored); the offset shift
    that follows the face's parameters is the calibration's, not the effect's."""
    return None if "eta_cov" not in block else joint_eta_cov(block, m, source)[:m, :m]


def face_undetermined(block: dict, m: int, source: str) -> np.ndarray | None:
    """Which of the face's ``m`` parameters the standing poses do not determine (``meta.effect.eta_undetermined``;
    None when none is, or the block predates the key)."""
    u = block.get("eta_undetermined")
    if u is None:
        return None
    u = np.asarray(u)
    if u.ndim != 1 or u.dtype != bool or len(u) < m:
        raise DataFormatError(f"{source}: meta.effect.eta_undetermined must be a list of booleans, one per meta.effect.eta "
                         f"value (at least {m}), got {block['eta_undetermined']!r}")
    return u[:m] if u[:m].any() else None


def sample_features(cal, ctx: AugContext, w, phi, R_WB, t_h) -> np.ndarray:
    """The standing features of every sample (``StandingData.features``; the previous pose is the sample itself)."""
    rcom = np.stack([cal.legs[k].com(phi[:, i]) for i, k in enumerate(ctx.legs)], axis=1)
    n_vert = np.einsum("kji,j->ki", ctx.R_nominal, np.array([0.0, 0.0, 1.0]))
    return StandingData(w, R_WB[:, 2, :], remove_yaw(R_WB), t_h, w, phi, np.nan_to_num(rcom), n_vert).features()


#: the keys of a block that are the joint fit's, replaced by the member's own in :func:`member_block`
JOINT_KEYS = ("name", "variant", "eta", "eta_cov", "eta_undetermined", "parameters", "members")


def member_block(block: dict, i: int, source: str = "calibration") -> dict:
    """Member ``i`` of a block of several effects (``meta.effect.members[i]``) as a single effect's block: the block's
    shared keys (``t_ref_s``, ``R_nominal``), the member's name, variant, parameters, its ``eta`` and the diagonal block
    of ``eta_cov`` of its ``eta_slice``. Checks the slice against the joint ``eta`` (a DataFormatError naming the key)."""
    mb = block["members"][i]
    key = f"meta.effect.members[{i}]"
    if not isinstance(mb, dict) or not isinstance(mb.get("name"), str):
        raise DataFormatError(f"{source}: {key} must be a table with a name (the effect's), got {mb!r}")
    eta_all = np.asarray(block.get("eta", []), float)
    sl = mb.get("eta_slice")
    if not (isinstance(sl, (list, tuple)) and len(sl) == 2 and all(isinstance(v, int) and not isinstance(v, bool) for v in sl)
            and 0 <= sl[0] <= sl[1] <= len(eta_all)):
        raise DataFormatError(f"{source}: {key}.eta_slice must be [start, stop] within meta.effect.eta ({len(eta_all)} values), got {sl!r}")
    eta = np.asarray(mb.get("eta", eta_all[sl[0]:sl[1]].tolist()), float)
    if eta.shape != (sl[1] - sl[0],) or not np.array_equal(eta, eta_all[sl[0]:sl[1]]):
        raise DataFormatError(f"{source}: {key}.eta must be meta.effect.eta[{sl[0]}:{sl[1]}] ({sl[1] - sl[0]} values), got "
                         f"{eta.size} values{' that differ from them' if eta.size == sl[1] - sl[0] else ''}")
    out = {k: v for k, v in block.items() if k not in JOINT_KEYS}
    out.update({k: v for k, v in mb.items() if k != "eta_slice"})
    out["eta"] = eta.tolist()
    out.setdefault("variant", {})
    out.setdefault("parameters", {})
    if "eta_cov" in block:
        C = joint_eta_cov(block, len(eta_all), source)
        out["eta_cov"] = C[sl[0]:sl[1], sl[0]:sl[1]].tolist()
    if "eta_undetermined" in block:
        out["eta_undetermined"] = list(block["eta_undetermined"])[sl[0]:sl[1]]
    return out


def joint_eta_cov(block: dict, m: int, source: str = "calibration") -> np.ndarray:
    """``meta.effect.eta_cov`` checked square with at least ``m`` rows (a DataFormatError naming the key)."""
    C = np.asarray(block["eta_cov"], float)
    if C.ndim != 2 or C.shape[0] != C.shape[1] or C.shape[0] < m:
        raise DataFormatError(f"{source}: meta.effect.eta_cov must be square with at least {m} rows (the members' parameters "
                         f"first), got {C.shape}")
    return C
