"""Settings of every stage: the one place their defaults live.

A run config (``config.py``, TOML) fills these frozen dataclasses: each of its
tables is a field of :class:`CalibrationSettings` and its keys are the fields of
that dataclass, so the valid keys, their types and defaults are stated here
alone (``CHOICES`` names the fields with a fixed set of values). Python users
build them directly and pass them to :func:`ftcal_nlp.calibrate` or to a stage
(``fit_hanging(..., settings=HangingSettings(...))``). Stage functions take a
settings object and keyword overrides of its fields; they never restate the
defaults in their own signatures (a function below a stage takes the values
from its caller, without defaults). A value out of range is a
:class:`~ftcal_nlp.core.errors.ConfigError` whose ``key`` is the config key
(``standing.poses.min_steady_s``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, TypeVar

from .calibration import REPORT_CANDIDATES
from .errors import ConfigError
from .solver import REL_EIG_TOL

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

__all__ = ["PoseExtraction", "FreeLoadSettings", "HangingSettings", "StandingSettings", "SelectionSettings", "DiagnoseSettings",
           "ChainThresholds", "HexapodChain", "FreeLoadChain",
           "OffsetsOnlySettings", "CorrectSettings", "CalibrationSettings", "with_overrides"]

T = TypeVar("T", bound="DataclassInstance")   # a settings dataclass


def with_overrides(settings: T | None, cls: type[T], overrides: dict[str, Any], where: str) -> T:
    """``settings`` (default ``cls()``) with the keyword ``overrides`` applied; unknown keys name the known ones.

    Asking for the report's baseline standing solver by keyword implies its K-norm (``weighting``)
    unless a weighting is given too (then a contradiction is an error, as in a config file)."""
    s = cls() if settings is None else settings
    if cls is StandingSettings and overrides.get("solver") == "baseline" and "weighting" not in overrides:
        overrides = {**overrides, "weighting": "knorm"}
    if not isinstance(s, cls):
        raise TypeError(f"{where}: settings must be a {cls.__name__}, got {type(s).__name__}")
    known = {f.name for f in fields(cls)}
    bad = sorted(set(overrides) - known)
    if bad:
        raise TypeError(f"{where}: unknown setting(s) {bad}; known: {sorted(known)}")
    return replace(s, **overrides) if overrides else s


def _check_choices(obj: Any, section: str) -> None:
    """Every field of ``obj`` named in its class's ``CHOICES`` (field -> (what it is, allowed values))
    holds one of the allowed values."""
    for name, (what, choices) in obj.CHOICES.items():
        value = getattr(obj, name)
        if value not in choices:
            raise ConfigError(f"{type(obj).__name__}.{name}: unknown {what} {value!r}; known: {list(choices)}", key=f"{section}.{name}")


@dataclass(frozen=True)
class PoseExtraction:
    """Settings of the steady-pose detector (report Sec. I-B); thresholds in SI units."""

    window_s: float = 0.31                  # Savitzky-Golay window; rounded to an odd number of samples
    deriv_threshold_N_s: float = 1.0        # steady when the force-derivative norm is below this
    min_steady_s: float = 1.5               # shortest steady run that makes a pose
    polyorder: int = 2                      # the report's 2nd-order filter
    deriv_norm: str = "legs"                # "legs": norm over all legs' force derivatives; "total": of their sum
    phi_rate_threshold_rad_s: float = 0.05  # a shaft moving faster than this separates two candidate poses
    max_mocap_missing: float = 0.0          # largest fraction of NaN orientations tolerated in a steady run
    max_gap_factor: float = 3.0             # time gaps over this many sample periods split the recording
    deriv_noise_factor: float = 2.0         # noisier readings: the threshold rises to this many times the median
                                            # derivative norm of the still samples (0: the fixed threshold only)

    CHOICES: ClassVar[dict[str, tuple[str, tuple[str, ...]]]] = {"deriv_norm": ("derivative norm", ("legs", "total"))}

    def __post_init__(self) -> None:
        _check_choices(self, "standing.poses")
        for name in ("window_s", "deriv_threshold_N_s", "min_steady_s", "phi_rate_threshold_rad_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"PoseExtraction.{name}: expected a positive number, got {getattr(self, name)!r}", key=f"standing.poses.{name}")
        if not self.deriv_noise_factor >= 0:
            raise ConfigError(f"PoseExtraction.deriv_noise_factor: expected a number >= 0, got {self.deriv_noise_factor!r}", key="standing.poses.deriv_noise_factor")
        if not 0.0 <= self.max_mocap_missing <= 1.0:
            raise ConfigError(f"PoseExtraction.max_mocap_missing: expected a fraction in [0, 1], got {self.max_mocap_missing!r}", key="standing.poses.max_mocap_missing")


HANGING_METHODS = ("nlp", "baseline")
STANDING_SOLVERS = ("ipopt", "baseline")
BALANCES = ("exact", "report")
WEIGHTINGS = ("fgls", "knorm")
COVARIANCES = ("gauss_newton", "sandwich")


@dataclass(frozen=True)
class HangingSettings:
    """Hanging stage (report Sec. III-A). ``smoothing``: ``"auto"`` (GCV) or the weight
    ``lam`` (1/m^2) of the CoM curve's second-difference penalty; ``n_grid``: CoM grid points."""

    CHOICES: ClassVar[dict[str, tuple[str, tuple[str, ...]]]] = {"method": ("hanging method", HANGING_METHODS)}

    method: str = "nlp"              # "nlp" or "baseline" (the report's own procedure)
    n_grid: int = 72
    smoothing: float | str = "auto"
    compare_baseline: bool = True    # also fit the report's baseline for the comparison figures

    def __post_init__(self) -> None:
        _check_choices(self, "hanging")
        if not (isinstance(self.n_grid, int) and not isinstance(self.n_grid, bool) and self.n_grid >= 8):
            raise ConfigError(f"HangingSettings.n_grid: expected an integer >= 8, got {self.n_grid!r}", key="hanging.n_grid")
        if not (self.smoothing == "auto" or (isinstance(self.smoothing, (int, float)) and not isinstance(self.smoothing, bool)
                                            and self.smoothing >= 0)):
            raise ConfigError(f"HangingSettings.smoothing: expected 'auto' or a non-negative number, got {self.smoothing!r}", key="hanging.smoothing")


@dataclass(frozen=True)
class StandingSettings:
    """Standing stage (report Sec. III-B) and the model it fits.

    ``model``: ``"auto"`` (the candidate model selection prefers) or a registered
    name / ``module:Class``; ``weighting``: the final fit's weight, ``"fgls"``
    (two-step feasible GLS) or ``"knorm"`` (eq. 8's K; selection always uses K);
    ``covariance``: ``"gauss_newton"`` or ``"sandwich"``; ``rel_eig_tol``: the
    identifiability threshold (``solver.py``)."""

    CHOICES: ClassVar[dict[str, tuple[str, tuple[str, ...]]]] = {
        "solver": ("solver", STANDING_SOLVERS), "balance": ("balance", BALANCES), "weighting": ("weighting", WEIGHTINGS),
        "covariance": ("covariance", COVARIANCES)}

    model: str = "auto"
    candidates: tuple[str, ...] = REPORT_CANDIDATES
    solver: str = "ipopt"            # "ipopt" or "baseline" (Cayley + alternating least squares)
    balance: str = "exact"           # "exact" (physics.py (E)) or "report" (eq. 9)
    weighting: str = "fgls"
    covariance: str = "gauss_newton"
    rel_eig_tol: float = REL_EIG_TOL
    compare_baseline: bool = True
    poses: PoseExtraction = field(default_factory=PoseExtraction)

    def __post_init__(self) -> None:
        _check_choices(self, "standing")
        if self.solver == "baseline" and self.weighting != "knorm":
            raise ConfigError(f"StandingSettings: weighting {self.weighting!r} needs solver 'ipopt': "
                              'solver = "baseline" is the report\'s K-norm method; set weighting = "knorm"', key="standing.weighting")


@dataclass(frozen=True)
class SelectionSettings:
    """Model selection (report Sec. IV-2): ``folds``-fold cross-validation with a seeded split, and BIC."""

    folds: int = 5
    seed: int = 0

    def __post_init__(self) -> None:
        if not (isinstance(self.folds, int) and self.folds >= 2):
            raise ConfigError(f"SelectionSettings.folds: expected an integer >= 2, got {self.folds!r}", key="selection.folds")


@dataclass(frozen=True)
class ChainThresholds:
    """The thresholds of the diagnosis' chain of effects (``diagnose/chain.py``), one set of names for every kind of
    evidence; each kind (:class:`HexapodChain`, :class:`FreeLoadChain`) has its own values.

    A candidate is named when the paired block-wise z of its held-out saving is ``z_min`` at least and the saving is
    at least ``min_floor_share`` of the floor's variance; the chain names ``max_effects`` at most. ``explained_min``:
    the share of the held-out excess over the floor that what is named must remove (hexapods: an effect, in the first
    ranking and each later one; free loads: the correlate ``where.explains`` names)."""

    SECTION: ClassVar[str] = "diagnose"

    z_min: float
    min_floor_share: float
    max_effects: int
    explained_min: float

    def __post_init__(self) -> None:
        key = f"{self.SECTION}.{{}}"
        if not self.z_min > 0:
            raise ConfigError(f"{type(self).__name__}.z_min: expected a positive number, got {self.z_min!r}", key=key.format("z_min"))
        for name in ("min_floor_share", "explained_min"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"{type(self).__name__}.{name}: expected a fraction in [0, 1], got {getattr(self, name)!r}",
                                  key=key.format(name))
        if not (isinstance(self.max_effects, int) and not isinstance(self.max_effects, bool) and self.max_effects >= 1):
            raise ConfigError(f"{type(self).__name__}.max_effects: expected an integer >= 1, got {self.max_effects!r}",
                              key=key.format("max_effects"))


#: the hexapod's values (evidence: standing poses, hanging legs, walking swing; each link a joint refit of the whole
#: calibration, ``diagnose/hexchain.py``); a config table ``[diagnose.hexapod]`` may override any of them
@dataclass(frozen=True)
class HexapodChain(ChainThresholds):
    """The hexapod's chain thresholds ([diagnose.hexapod])."""

    SECTION: ClassVar[str] = "diagnose.hexapod"

    z_min: float = 3.0
    min_floor_share: float = 0.05
    max_effects: int = 3
    explained_min: float = 0.5


#: the free loads' values (evidence: every sample of the load in blocks of holds, ``diagnose/chain.py``; the floor's
#: variance there is ``6 N``, N samples in units of the noise variance)
@dataclass(frozen=True)
class FreeLoadChain(ChainThresholds):
    """The free loads' chain thresholds ([diagnose.free_loads])."""

    SECTION: ClassVar[str] = "diagnose.free_loads"

    z_min: float = 3.0
    min_floor_share: float = 0.01
    max_effects: int = 4
    explained_min: float = 0.3


@dataclass(frozen=True)
class DiagnoseSettings:
    """Sim-to-real gap diagnosis: ``effects`` the candidate names (None: the whole library),
    ``folds``/``seed`` its cross-validation; ``joint_refit``: refit the whole calibration with
    the named effect (``diagnose/refit.py``) and report its shrinkage; ``hexapod``/``free_loads``:
    the chain's thresholds (:class:`ChainThresholds`) for each kind of evidence."""

    enabled: bool = True
    effects: tuple[str, ...] | None = None
    folds: int = 5
    seed: int = 0
    joint_refit: bool = True
    hexapod: HexapodChain = field(default_factory=HexapodChain)
    free_loads: FreeLoadChain = field(default_factory=FreeLoadChain)


@dataclass(frozen=True)
class OffsetsOnlySettings:
    """Re-estimate offsets alone from standing poses, keeping an earlier calibration (report Sec. V)."""

    calibration: Path | None = None


@dataclass(frozen=True)
class CorrectSettings:
    """Correction of walking recordings (``contact.py``, ``tracking.py``, ``uncertainty.py``).

    ``track_offsets``: re-estimate each leg's offsets over the recording from its swing phases;
    ``knot_s``: knot spacing (s) of their cubic B-spline, ``penalty``: weight of its second-difference
    penalty relative to the data's; contact: a foot is in swing when its normal force above the
    swing baseline drops below ``contact_enter_z`` standard errors and in stance again above
    ``contact_leave_z``; the baseline is the ``contact_quantile`` of the normal force in windows of
    ``contact_window_s`` whose ``1 - contact_quantile`` quantile exceeds it by ``contact_min_gap_N``
    (about half a foot's share of the weight; windows without swing keep the calibration's zero)."""

    track_offsets: bool = False
    knot_s: float = 20.0
    penalty: float = 1e-3
    contact_window_s: float = 30.0
    contact_quantile: float = 0.1
    contact_enter_z: float = 5.0
    contact_leave_z: float = 10.0
    contact_min_gap_N: float = 8.0

    def __post_init__(self) -> None:
        for name in ("knot_s", "contact_window_s", "contact_enter_z", "contact_leave_z", "contact_min_gap_N"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"CorrectSettings.{name}: expected a positive number, got {getattr(self, name)!r}", key=f"correct.{name}")
        if not self.penalty >= 0:
            raise ConfigError(f"CorrectSettings.penalty: expected a number >= 0, got {self.penalty!r}", key="correct.penalty")
        if not 0 < self.contact_quantile < 0.5:
            raise ConfigError(f"CorrectSettings.contact_quantile: expected a number in (0, 0.5), got {self.contact_quantile!r}", key="correct.contact_quantile")
        if not self.contact_leave_z >= self.contact_enter_z:
            raise ConfigError(f"CorrectSettings: contact_leave_z ({self.contact_leave_z}) must be >= contact_enter_z "
                              f"({self.contact_enter_z}) (hysteresis)", key="correct.contact_leave_z")


@dataclass(frozen=True)
class FreeLoadSettings:
    """Free loads (``DATA_FORMAT.md`` section 5; ``ftcal_nlp.estimate.freeload``): quasi-static sample selection and the fit.

    A sample is used where the body's rate of turn, every joint's rate and the force-derivative norm
    (Savitzky-Golay, ``window_s``, ``polyorder``) are under their thresholds; each threshold rises to
    ``noise_factor`` times the median of its rate over the samples the other two call still, when that is
    larger (noisier streams, as the standing poses do). ``mount_rotation``: estimate the transducer's mounting
    rotation; ``prior_weight``: weight of the load's nominal values (the URDF's) relative to the information of
    each parameter, which pins only what the data leave undetermined; ``gravity_tilt``: a world tilt of the
    orientation stream (2 parameters); ``recording_tilt``: a tilt of each recording that gives gravity by
    ``gravity_body`` only (2 parameters each; ``"auto"``: where the data determine it with everything else, else
    held at 0 with a note); ``loads``: transducer -> load name or
    ``module:Class`` instead of the dataset's kind. A recording whose samples lie farther apart than ``window_s`` is
    a list of poses: every sample is a hold. ``sensor_matrix``: the sensor's own matrix refitted in situ
    (``freeload/sensor_matrix.py``): ``"none"`` (the factory matrix kept; nothing else changes), ``"force"`` (the 3x3
    force block of ``C``), ``"full"`` (6x6), ridge-regularised towards the factory matrix with the weight of
    ``sensor_matrix_ridge`` (dimensionless, per sample per unit entry squared; ``inf``: the factory matrix) of least
    held-out error over ``sensor_matrix_folds`` contiguous blocks (one-se rule); ``sensor_matrix_mass_rel_sd``: the
    relative sd of a weighed ``load_mass_kg``, which fixes the force gain the load's mass otherwise absorbs."""

    CHOICES: ClassVar[dict[str, tuple[str, tuple[str, ...]]]] = {"sensor_matrix": ("sensor matrix mode", ("none", "force", "full"))}

    window_s: float = 0.31
    polyorder: int = 2
    rotation_rate_threshold_rad_s: float = 0.02
    joint_rate_threshold_rad_s: float = 0.02
    deriv_threshold_N_s: float = 1.0
    noise_factor: float = 2.0
    max_gap_factor: float = 3.0
    min_samples: int = 0             # fewest quasi-static samples; 0: twice the unknowns in equations (6 per sample)
    mount_rotation: bool = True
    gravity_tilt: bool = True   # a world tilt of the orientation stream (2 dof), where the recordings give R_WB per sample
    recording_tilt: bool | str = "auto"  # a tilt per gravity_body-only recording (2 dof each): true, false or "auto"
    prior_weight: float = 1e-8
    rel_eig_tol: float = REL_EIG_TOL
    loads: dict = field(default_factory=dict)
    sensor_matrix: str = "none"
    sensor_matrix_ridge: tuple[float, ...] = (0.0, 1.0, 10.0, 100.0, 1e3, 1e4, 1e5, 1e6, float("inf"))
    sensor_matrix_folds: int = 5
    sensor_matrix_mass_rel_sd: float = 1e-3

    def __post_init__(self) -> None:
        _check_choices(self, "free_load")
        if not self.sensor_matrix_ridge or any(not v >= 0 for v in self.sensor_matrix_ridge):
            raise ConfigError(f"sensor_matrix_ridge: expected a list of weights >= 0 (inf: the factory matrix), got "
                              f"{self.sensor_matrix_ridge!r}", key="free_load.sensor_matrix_ridge")
        if not self.sensor_matrix_folds >= 2:
            raise ConfigError(f"sensor_matrix_folds: expected at least 2, got {self.sensor_matrix_folds!r}", key="free_load.sensor_matrix_folds")
        if not self.sensor_matrix_mass_rel_sd > 0:
            raise ConfigError(f"sensor_matrix_mass_rel_sd: expected a positive fraction, got {self.sensor_matrix_mass_rel_sd!r}",
                              key="free_load.sensor_matrix_mass_rel_sd")
        for name in ("window_s", "rotation_rate_threshold_rad_s", "joint_rate_threshold_rad_s", "deriv_threshold_N_s", "max_gap_factor"):
            if not getattr(self, name) > 0:
                raise ValueError(f"FreeLoadSettings.{name}: expected a positive number, got {getattr(self, name)!r}")
        if not self.noise_factor >= 0 or not self.prior_weight >= 0:
            raise ValueError("FreeLoadSettings: noise_factor and prior_weight must be >= 0")
        if self.recording_tilt not in (True, False, "auto"):
            raise ConfigError(f"recording_tilt: expected true, false or \"auto\", got {self.recording_tilt!r}", key="free_load.recording_tilt")


@dataclass(frozen=True)
class CalibrationSettings:
    """Everything :func:`ftcal_nlp.calibrate` needs besides the dataset."""

    hanging: HangingSettings = field(default_factory=HangingSettings)
    standing: StandingSettings = field(default_factory=StandingSettings)
    selection: SelectionSettings = field(default_factory=SelectionSettings)
    diagnose: DiagnoseSettings = field(default_factory=DiagnoseSettings)
    correct: CorrectSettings = field(default_factory=CorrectSettings)
    free_load: FreeLoadSettings = field(default_factory=FreeLoadSettings)
