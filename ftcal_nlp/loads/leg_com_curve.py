"""The hexapod leg: a CoM that moves with the shaft angle ``phi`` (report Sec. III-A).

Its model, ``f = m g R_j a_j + f_o``, ``t = r(phi) x f + t_o`` with the CoM curve
``r(phi)`` on a periodic grid, is estimated by the hanging calibration
(:func:`ftcal_nlp.estimate.hanging.fit_hanging`: the smoothness-penalised QP over ``phi``
and the exact-rotation NLP, from opposite hanging pairs), which the pipeline calls
for the transducers of this kind: the plug-in names the kind in the registry and
imports no estimator (loads sit below the stages that fit them).
"""

from __future__ import annotations


class LegComCurve:
    """A hexapod leg's load (module docstring)."""

    name = "leg_com_curve"
    kind = "leg_com_curve"
