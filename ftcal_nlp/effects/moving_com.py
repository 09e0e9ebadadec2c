"""moving_com: the legs' CoM motion that a fixed-CoM balance omits.

Injected: nothing (``MovingComInjector``: exact physics); the gap appears when the calibration
uses the report's fixed-CoM balance (eq. 9), so the validation runs it with ``balance = "report"``
(``needs_report_balance``).

Model face: the exact balance (E) instead of eq. 9, no new parameter.

Correction: none per foot (a body effect).
"""

from __future__ import annotations

from .faces import ParamBlock
from .injection import EffectInjector, Magnitude
from .unit import Effect


class MovingComInjector(EffectInjector):
    """Exact physics (nothing added): the legs' CoMs move, as they always do."""

    name = "moving_com"
    magnitude = Magnitude("(none: exact physics; a calibration with balance = 'report')", (1.0, 1.0), 1.0)

    def __init__(self, scale: float | None = None, seed: int = 0):
        super().__init__(1.0 if scale is None else scale, seed)


class MovingCom(Effect):
    name = "moving_com"
    description = "the legs' CoM motion that a fixed-CoM balance omits"
    explains = "shaft_angle"
    kind = "body"
    injector_cls = MovingComInjector
    needs_report_balance = True

    def standing_params(self, ctx):
        return ParamBlock(())

    def standing_balance(self, balance: str) -> str:
        return "exact"


EFFECT = MovingCom()
