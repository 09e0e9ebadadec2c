"""Standing stage (report Sec. I-B, III-B): poses, balance, error models, solvers, results."""

from .baseline import BaselineSettings
from .fit import fit_standing
from .nlp import SolverError
from .poses import PoseExtraction, Poses, extract_poses
from .result import StandingResult

__all__ = ["extract_poses", "PoseExtraction", "Poses", "fit_standing", "StandingResult", "SolverError", "BaselineSettings"]
