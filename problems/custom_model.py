"""A researcher's own error model, worked example (load as ``problems.custom_model:CommonRotation``
or ``path/to/problems/custom_model.py:CommonRotation``; in a run config: ``[standing] model = ...``
or in ``candidates``).

Hypothesis: the six transducers sit on one plate that was mounted slightly rotated as a whole,
so they share ONE mounting rotation ``R_c`` (``R_k = R_c R_nominal_k``), while each transducer
has its own translation ``p'_k``. DOF 3 + 18.

What a model declares (see ``ftcal_nlp.models.base``):

* ``name`` (used in tables and the calibration) and ``description`` (Table I's "Model" column);
* ``build(ctx)`` returning a ``ModelSpec``: CasADi SX variables with start values and bounds
  (``so3_variable`` for a rotation with exact SO(3) constraints, ``vector_variable`` for a vector),
  the K rotations ft_k -> B and the K translations p'_k (ft_k origin relative to the CoM of the body
  without legs, B axes) as expressions of the variables, and the degrees of freedom.

``ctx`` carries the nominal transducer poses of ``robot.toml`` (``R_nominal`` (K,3,3), ``p_nominal``
(K,3)), the leg names and the prior calibration. Everything else (balance, IPOPT, standard errors,
undetermined directions, BIC and cross-validation) comes with the framework.

A second example, ``YawOnly``, uses plain angles instead of a constrained matrix: each transducer
may be turned about the body z axis only (R_k = Rz(psi_k) R_nominal_k), translations free.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ftcal_nlp.models import ErrorModel, ModelContext, ModelSpec, make_spec, so3_variable, vector_variable


class CommonRotation(ErrorModel):
    name = "common_rotation"
    description = "One common rotation + six translations"

    def build(self, ctx: ModelContext) -> ModelSpec:
        R_c, rot_block = so3_variable("R_common", np.eye(3))
        R = [ca.mtimes(R_c, ca.DM(ctx.R_nominal[k])) for k in range(ctx.K)]
        blocks, p = [rot_block], []
        for k, leg in enumerate(ctx.legs):
            v, b = vector_variable(f"p_prime_{leg}", ctx.p_nominal[k], bound=1.0)
            p.append(v)
            blocks.append(b)
        return make_spec(blocks, R, p, dof=3 + 3 * ctx.K, dof_label=f"3+{3 * ctx.K}")


class YawOnly(ErrorModel):
    name = "yaw_only"
    description = "Six rotations about z + six translations"

    def build(self, ctx: ModelContext) -> ModelSpec:
        psi, psi_block = vector_variable("psi", np.zeros(ctx.K), bound=np.radians(20.0), labels=ctx.legs)
        blocks, R, p = [psi_block], [], []
        for k, leg in enumerate(ctx.legs):
            c, s = ca.cos(psi[k]), ca.sin(psi[k])
            Rz = ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))
            R.append(ca.mtimes(Rz, ca.DM(ctx.R_nominal[k])))
            v, b = vector_variable(f"p_prime_{leg}", ctx.p_nominal[k], bound=1.0)
            p.append(v)
            blocks.append(b)
        return make_spec(blocks, R, p, dof=4 * ctx.K, dof_label=f"{ctx.K}+{3 * ctx.K}")
