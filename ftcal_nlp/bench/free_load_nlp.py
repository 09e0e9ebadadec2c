"""The free-load NLP (``ftcal_nlp.estimate.freeload``) as the benches call it: a simulated dataset written in the
interchange format, read by the section-5 reader, fitted by ``fit_free_load`` (the fit alone timed: quasi-static
selection, compression, IPOPT, covariance), its estimate put in ``crb.free_load``' parameter order."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np


def nlp_estimate(res, workdir: Path) -> tuple[np.ndarray, float, int]:
    """``(theta, wall s, samples used)`` of the NLP on the simulation ``res`` (written into ``workdir``), the
    fields of ``accuracy_loads.LoadEstimate``."""
    from ..core.data import read_dataset
    from ..estimate.freeload import fit_free_load
    from ..sim.free import write_free_load

    ds = read_dataset(write_free_load(res, Path(workdir), overwrite=True))
    leg = res.config.transducer
    quiet = logging.getLogger("ftcal_nlp.estimate.freeload")
    level = quiet.level
    quiet.setLevel(logging.ERROR)        # a URDF load's undetermined directions are expected here (rows say so)
    try:
        t0 = time.perf_counter()
        fit = fit_free_load(ds, leg)
        wall = time.perf_counter() - t0
    finally:
        quiet.setLevel(level)
    return estimate_theta(fit), wall, int(fit.n_used)


def estimate_theta(fit) -> np.ndarray:
    """A ``FreeLoadResult`` in ``crb.free_load`` order: payload ``(offset 6, mass, CoM 3[, tilt 2], mount rotvec 3)`` (the
    CoM ``h / m``); URDF load ``(offset 6, per joint group (mass, first moment 3)[, tilt 2], mount rotvec 3)`` (both
    group by the nearest movable joint, first moments in the frame of that joint's child link); the world tilt where
    the fit has it (``crb.TILT_NAMES``)."""
    tilt = np.zeros(0) if fit.tilt is None else np.asarray(fit.tilt, float)
    if fit.load.kind == "rigid_payload":
        m, h = fit.theta[0], fit.theta[1:4]
        return np.concatenate([fit.offset, [m], h / m, tilt, fit.mount_rotvec])
    return np.concatenate([fit.offset, fit.theta, tilt, fit.mount_rotvec])
