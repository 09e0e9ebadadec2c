"""The report's four error models (Sec. IV-2, Table I) and the offsets-only model (Sec. V).

With ``R_nom_k``, ``p_nom_k`` the design-file pose of ft_k in B and ``c`` the CoM
of the body without legs in B (the report's ``-p_B^C``):

* ``full``         R_k free on SO(3), p'_k free                      DOF 18+18
* ``rot6_trans1``  R_k free on SO(3), p'_k = p_nom_k - c              DOF 18+3
* ``trans6``       R_k = R_nom_k,     p'_k free                       DOF 18
* ``trans1``       R_k = R_nom_k,     p'_k = p_nom_k - c              DOF 3
* ``offsets``      R_k, p'_k of the prior calibration, w_o,k free     DOF 6K

``R_k = R_tilde_k R_nom_k``: the mounting error ``R_tilde_k`` acts in B after the
nominal rotation, and the estimate is the product. Free rotations start at
``R_nom_k``, free translations at ``p_nom_k`` (``c = 0``).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .base import ErrorModel, ModelContext, ModelSpec, make_spec, so3_variable, vector_variable

# Bounds on translations: far beyond any plausible mounting or CoM error, they only
# keep a diverging solve finite.
TRANSLATION_BOUND_M = 2.0


def _rotations(ctx: ModelContext, free: bool):
    if not free:
        return [ca.SX(ctx.R_nominal[k]) for k in range(ctx.K)], []
    out = [so3_variable(f"R_{leg}", ctx.R_nominal[k]) for k, leg in enumerate(ctx.legs)]
    return [r for r, _ in out], [b for _, b in out]


def _translations(ctx: ModelContext, each: bool):
    """Six free ``p'_k`` (``each``), or nominal positions less one free body CoM ``c``:
    returns the K translations, their variable blocks and ``c`` (None when each is free)."""
    if each:
        out = [vector_variable(f"p_prime_{leg}", ctx.p_nominal[k], TRANSLATION_BOUND_M) for k, leg in enumerate(ctx.legs)]
        return [v for v, _ in out], [b for _, b in out], None
    c, b = vector_variable("com_body", np.zeros(3), TRANSLATION_BOUND_M)
    return [ca.DM(ctx.p_nominal[k]) - c for k in range(ctx.K)], [b], c


class Full(ErrorModel):
    name = "full"
    description = "Full (Six rotations + six translations)"
    baseline_rotations, baseline_translations = "each", "each"

    def build(self, ctx: ModelContext) -> ModelSpec:
        R, rb = _rotations(ctx, True)
        p, pb, _ = _translations(ctx, True)
        return make_spec(rb + pb, R, p, dof=6 * ctx.K, dof_label=f"{3 * ctx.K}+{3 * ctx.K}")


class Rot6Trans1(ErrorModel):
    name = "rot6_trans1"
    description = "Six rotations + single translation"
    baseline_rotations, baseline_translations = "each", "common"

    def build(self, ctx: ModelContext) -> ModelSpec:
        R, rb = _rotations(ctx, True)
        p, pb, c = _translations(ctx, False)
        return make_spec(rb + pb, R, p, com_body=c, dof=3 * ctx.K + 3, dof_label=f"{3 * ctx.K}+3")


class Trans6(ErrorModel):
    name = "trans6"
    description = "Six translations only"
    baseline_rotations, baseline_translations = "nominal", "each"

    def build(self, ctx: ModelContext) -> ModelSpec:
        R, rb = _rotations(ctx, False)
        p, pb, _ = _translations(ctx, True)
        return make_spec(rb + pb, R, p, dof=3 * ctx.K, dof_label=f"{3 * ctx.K}")


class Trans1(ErrorModel):
    name = "trans1"
    description = "Single translation"
    baseline_rotations, baseline_translations = "nominal", "common"

    def build(self, ctx: ModelContext) -> ModelSpec:
        R, rb = _rotations(ctx, False)
        p, pb, c = _translations(ctx, False)
        return make_spec(rb + pb, R, p, com_body=c, dof=3, dof_label="3")


class OffsetsOnly(ErrorModel):
    """Report Sec. V: offsets drift; re-estimate ``w_o`` with everything else of the prior kept.

    From standing poses alone only the six combinations ``sum_k Ad_k w_o,k`` (in B)
    are determined (every pose sees the offsets through that sum, rotated by the
    body orientation); the other ``6K - 6`` directions stay at the prior and are
    reported as unidentified.
    """

    name = "offsets"
    description = "Offsets only (rotations and translations kept)"
    baseline_rotations, baseline_translations, baseline_offsets = "prior", "prior", True

    def build(self, ctx: ModelContext) -> ModelSpec:
        offsets, _, R_prior, p_prior = ctx.prior.stacked(ctx.legs)
        blocks, w = [], []
        for k, leg in enumerate(ctx.legs):
            v, b = vector_variable(f"w_o_{leg}", offsets[k], np.inf, labels=("fx", "fy", "fz", "tx", "ty", "tz"))
            w.append(v)
            blocks.append(b)
        R = [ca.SX(R_prior[k]) for k in range(ctx.K)]
        p = [ca.SX(p_prior[k]) for k in range(ctx.K)]
        return make_spec(blocks, R, p, offsets=tuple(w), dof=6 * ctx.K, dof_label=f"{6 * ctx.K}")
