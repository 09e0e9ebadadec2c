"""Several effects as one augmentation of the calibration model (issue 23, item 2: the hexapod chain).

The hexapod diagnosis names effects one after another (``diagnose/hexchain.py``); the effects named so far and
the next candidate are fitted together with the calibration. :class:`Combined` makes of effect units ``E_1 .. E_n``
(each a chosen variant) one :class:`~.unit.Effect`, so that the standing problem
(``diagnose/standing_fit.AugmentedProblem``), the linear faces (``diagnose/linear_fit.py``) and the joint refit
(``diagnose/refit.py``) take it as they take one effect:

* standing (eq. (A) of ``faces.py``): ``eta = [eta_1; ..; eta_n]`` (names ``<effect>:<name>``); to first order the
  corrections add up,

      c_k = w_k + sum_i (c_k,i - w_k),   z~ = Z_1 .. Z_n z,   e_p = sum_i e_p,i

  (each face is linear in the pose features, so the sum is: the problem stays quadratic in the moments);
  the offset shift (``shifts_offsets``) is one constant wrench whoever asks for it; the balance is the members'
  (``standing_balance`` in turn);
* hanging, walking swing: the members' linear faces side by side (:func:`~.faces.stack_faces`);
* ``standing_from_hanging``: each member's, its indices moved to its place in ``eta``;
  ``standing_prior_from_hanging`` the same, its names prefixed as the stacked hanging face's;
* the joint refit's variants: the last member's ``joint_variants`` (the members before it come as the chain's
  joint refits chose them);
* the correction for ``correct`` (:meth:`Combined.correct`, a block with ``members``: ``diagnose/refit.py``,
  ``JointRefit.effect_block``): the same first-order sum the fit used, each member's correction evaluated on the
  recorded samples (not on the readings another member corrected),

      w' = w + sum_i (w'_i - w),   R_WB' = R_WB Z_1^T .. Z_n^T (up to the order of the maps: only a motion-capture
      bias has one),

  which is exactly the fitted model (the fitted parameters are those of the sum). Applying the members in sequence,
  ``c_2(c_1(w))``, is the same where the corrections after the first are shifts that do not depend on the readings
  (a casing load, an offset drift), and differs by the products of the corrections where they do (a gain or
  crosstalk matrix, a chassis flex or a nonlinearity applied to readings a casing load corrected: second-order
  terms the fit did not have). The members whose correction is their standing face
  (``unit.corrects_by_face``: sensor effects with a hexapod face) are evaluated together as one face, so the
  covariance of the corrected readings
  ``J Sigma_eta J^T`` uses the joint ``eta_cov`` with its cross-member terms; the others (an offset drift's rates,
  a motion-capture bias on the orientations, body effects: nothing per foot) apply their own correction with their
  block (``faces.member_block``), and their covariances add: the drift rates' correlations with the standing
  face's ``eta`` are not stored (they come from the hanging regression); a motion-capture bias leaves the readings
  as they are (no term is left out), its orientation map is not propagated.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..core.errors import DataFormatError
from .faces import ParamBlock, correct_by_face, joint_eta_cov, member_block, stack_faces
from .unit import Effect, corrects_by_face

SEP = ":"


class Combined(Effect):
    """The effects ``members`` (variants, in the order named) as one augmentation (module docstring)."""

    kind = "sensor"
    diagnosed_on = frozenset({"hexapod"})

    def __init__(self, members):
        members = tuple(members)
        if not members or any(isinstance(m, Combined) for m in members):
            raise ValueError("Combined: expected one or more effect units (not Combined)")
        names = [m.name for m in members]
        if len(set(names)) != len(names):
            raise ValueError(f"Combined: an effect appears twice in {names}")
        self.members = members

    # the class attributes a unit declares, from the members
    @property
    def name(self) -> str:   # type: ignore[override]
        return "+".join(m.name for m in self.members)

    @property
    def shifts_offsets(self) -> bool:   # type: ignore[override]
        return any(m.shifts_offsets for m in self.members)

    @property
    def joint_holds_offset_shift(self) -> bool:   # type: ignore[override]
        # one shift for all: held only when every member that shifts offsets holds it
        return self.shifts_offsets and all(m.joint_holds_offset_shift for m in self.members if m.shifts_offsets)

    @property
    def needs_report_balance(self) -> bool:   # type: ignore[override]
        return any(m.needs_report_balance for m in self.members)

    @property
    def design_face(self) -> bool:   # type: ignore[override]
        return any(m.design_face for m in self.members)

    @property
    def explains(self):
        return self.members[0].explains

    @property
    def variant(self) -> dict:
        """Per member its variant (``{name: variant}``, in order)."""
        return {m.name: dict(m.variant) for m in self.members}

    @property
    def label(self) -> str:
        return " + ".join(m.label for m in self.members)

    def variants(self):
        return (self,)

    def joint_variants(self):
        last = self.members[-1].joint_variants()
        return tuple(Combined(self.members[:-1] + (v,)) for v in last)

    def joint_variant(self):
        return self.joint_variants()[0]

    # ---- standing face
    def _blocks(self, ctx):
        return [m.standing_params(ctx) for m in self.members]

    def standing_params(self, ctx):
        blocks = [(m, b) for m, b in zip(self.members, self._blocks(ctx)) if b is not None and b.m]
        if not blocks:
            return None
        return ParamBlock(tuple(f"{m.name}{SEP}{n}" for m, b in blocks for n in b.names),
                          np.concatenate([b.x0 for _, b in blocks]), np.concatenate([b.lb for _, b in blocks]),
                          np.concatenate([b.ub for _, b in blocks]))

    def split(self, ctx) -> list[slice]:
        """Per member the slice of ``eta`` its parameters take (empty: none)."""
        out, c0 = [], 0
        for b in self._blocks(ctx):
            m = b.m if b is not None else 0
            out.append(slice(c0, c0 + m))
            c0 += m
        return out

    def standing(self, eta, pose, ctx):
        c = list(pose.w)
        zmap, extra = None, None
        for m, sl in zip(self.members, self.split(ctx)):
            ci, Zi, ei = m.standing(eta[sl], pose, ctx)
            c = [ck + (cik - wk) for ck, cik, wk in zip(c, ci, pose.w)]
            if Zi is not None:
                zmap = Zi if zmap is None else ca.mtimes(zmap, Zi)
            if ei is not None:
                extra = ei if extra is None else extra + ei
        return c, zmap, extra

    def standing_balance(self, balance: str) -> str:
        for m in self.members:
            balance = m.standing_balance(balance)
        return balance

    def standing_from_hanging(self, hanging: dict, ctx) -> dict:
        out = {}
        for m, sl in zip(self.members, self.split(ctx)):
            mine = {n[len(m.name) + 1:]: v for n, v in hanging.items() if n.startswith(m.name + SEP)}
            for i, v in m.standing_from_hanging(mine, ctx).items():
                out[sl.start + i] = v
        return out

    def standing_prior_from_hanging(self, ctx) -> dict:
        out = {}
        for m, sl in zip(self.members, self.split(ctx)):
            for i, n in m.standing_prior_from_hanging(ctx).items():
                out[sl.start + i] = f"{m.name}{SEP}{n}"
        return out

    # ---- linear faces
    def hanging_features(self, legs):
        return stack_faces([(m.name, m.hanging_features(legs)) for m in self.members], legs)

    def swing_features(self, legs):
        return stack_faces([(m.name, m.swing_features(legs)) for m in self.members], legs)

    def member_parameters(self, parameters: dict) -> list[dict]:
        """``parameters`` (``name -> value``, names ``<effect>:<name>`` or ``hanging:<effect>:<name>``) split per
        member, the prefix taken off (``hanging:`` kept)."""
        out = []
        for m in self.members:
            mine = {}
            for n, v in parameters.items():
                pre, rest = ("hanging:", n[len("hanging:"):]) if n.startswith("hanging:") else ("", n)
                if rest.startswith(m.name + SEP):
                    mine[pre + rest[len(m.name) + 1:]] = v
            out.append(mine)
        return out

    # ---- the correction for `correct`
    def correct(self, cal, block: dict, ctx, w: np.ndarray, phi: np.ndarray, R_WB: np.ndarray, t_h: np.ndarray, *,
                with_cov: bool = True, source: str = "calibration"):
        """``(w', R_WB', cov)`` corrected for every member (module docstring) with the parameters of ``block`` (a block
        with ``members``, one per member in order)."""
        members = block.get("members")
        if not isinstance(members, (list, tuple)) or len(members) != len(self.members):
            raise DataFormatError(f"{source}: meta.effect.members must list the {len(self.members)} effects of {self.name!r}, "
                             f"got {members!r}")
        subs = [member_block(block, i, source) for i in range(len(self.members))]
        for i, (m, sb) in enumerate(zip(self.members, subs)):
            if sb["name"] != m.name:
                raise DataFormatError(f"{source}: meta.effect.members[{i}].name is {sb['name']!r}, expected {m.name!r} "
                                 f"(meta.effect.name {self.name!r})")
            p = m.standing_params(ctx)
            need = p.m if p is not None else 0
            if block.get("eta") and len(sb["eta"]) != need:
                raise DataFormatError(f"{source}: meta.effect.members[{i}].eta has {len(sb['eta'])} values, {m.name} needs {need}")
        face = [i for i, m in enumerate(self.members) if corrects_by_face(m)]
        w_out, R_out, cov = w, R_WB, None
        if face:
            # one face for the face members: their corrections add up (``standing``) and eta_cov's cross terms enter J Sigma J^T
            idx = np.concatenate([np.arange(*block["members"][i]["eta_slice"]) for i in face]).astype(int)
            sub = {"eta": np.concatenate([np.asarray(subs[i]["eta"], float) for i in face]).tolist()}
            if with_cov and "eta_cov" in block:
                C = joint_eta_cov(block, int(idx.max()) + 1 if len(idx) else 0, source)
                sub["eta_cov"] = C[np.ix_(idx, idx)].tolist()
                if "eta_undetermined" in block:
                    sub["eta_undetermined"] = [bool(block["eta_undetermined"][j]) for j in idx]
            unit = self.members[face[0]] if len(face) == 1 else Combined([self.members[i] for i in face])
            w_out, R_out, cov = correct_by_face(unit, cal, sub, ctx, w, phi, R_WB, t_h, with_cov=with_cov, source=source)
        for i, m in enumerate(self.members):
            if i in face:
                continue
            wi, Ri, ci = m.correct(cal, subs[i], ctx, w, phi, R_WB, t_h, with_cov=with_cov, source=source)
            if wi is not w:
                w_out = w_out + (np.asarray(wi, float) - w)
            if Ri is not R_WB:   # R_i = R_WB Z_i^T: compose Z_i^T = R_WB^T R_i
                R_out = np.einsum("nij,njk->nik", R_out, np.einsum("nji,njk->nik", R_WB, Ri))
            if ci is not None:
                cov = ci if cov is None else cov + ci
        return w_out, R_out, cov

    def __repr__(self) -> str:
        return f"<effects {self.name}>"
