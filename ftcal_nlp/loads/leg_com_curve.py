"""The hexapod leg: a CoM that moves with the shaft angle ``phi`` (report Sec. III-A).

Its model, ``f = m g R_j a_j + f_o``, ``t = r(phi) x f + t_o`` with the CoM curve
``r(phi)`` on a periodic grid, is estimated by the hanging calibration
(:func:`ftcal_nlp.hanging.fit_hanging`: the smoothness-penalised QP over ``phi``
and the exact-rotation NLP, from opposite hanging pairs); this plug-in only
delegates to it, so a hexapod dataset gives the same numbers as before loads
were plug-ins.
"""

from __future__ import annotations

from typing import Sequence


class LegComCurve:
    """A hexapod leg's load (module docstring)."""

    name = "leg_com_curve"
    kind = "leg_com_curve"

    def fit(self, recordings: Sequence, robot, settings=None, **overrides):
        """The hanging calibration of every leg of ``robot`` (:func:`ftcal_nlp.hanging.fit_hanging`)."""
        from ..hanging import fit_hanging

        return fit_hanging(recordings, robot, settings, **overrides)
