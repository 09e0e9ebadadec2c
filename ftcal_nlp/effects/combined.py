"""Several effects as one augmentation of the calibration model (issue 23, item 2: the hexapod chain).

The hexapod diagnosis names effects one after another (``diagnose/hexchain.py``); the effects named so far and
the next candidate are fitted together with the calibration. :class:`Combined` makes of effect units ``E_1 .. E_n``
(each a chosen variant) one :class:`~.unit.Effect`, so that the standing problem
(``diagnose/standing_fit.AugmentedProblem``), the linear faces (``diagnose/linear_fit.py``) and the joint refit
(``diagnose/joint.py``) take it as they take one effect:

* standing (eq. (A) of ``faces.py``): ``eta = [eta_1; ..; eta_n]`` (names ``<effect>:<name>``); to first order the
  corrections add up,

      c_k = w_k + sum_i (c_k,i - w_k),   z~ = Z_1 .. Z_n z,   e_p = sum_i e_p,i

  (each face is linear in the pose features, so the sum is: the problem stays quadratic in the moments);
  the offset shift (``shifts_offsets``) is one constant wrench whoever asks for it; the balance is the members'
  (``standing_balance`` in turn);
* hanging, walking swing: the members' linear faces side by side (:func:`~.faces.stack_faces`);
* ``standing_from_hanging``: each member's, its indices moved to its place in ``eta``;
* the joint refit's variants: the last member's ``joint_variants`` (the members before it come as the chain's
  joint refits chose them).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .faces import ParamBlock, stack_faces
from .unit import Effect

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
    def needs_report_balance(self) -> bool:   # type: ignore[override]
        return any(m.needs_report_balance for m in self.members)

    @property
    def design_face(self) -> bool:   # type: ignore[override]
        return any(m.design_face for m in self.members)

    @property
    def explains(self):   # type: ignore[override]
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

    def __repr__(self) -> str:
        return f"<effects {self.name}>"
