"""The free-load estimator (``DATA_FORMAT.md`` section 5, issue 22): one transducer's offsets, its load's
parameters and its mounting rotation from hanging recordings with gravity per sample.

API (the result object other modules build on):

* ``fit_free_loads(dataset, settings) -> FreeLoadResults``: every transducer whose load is not a hexapod leg
  (``Dataset.free_load_legs``), independently except those sharing a ``gravity_body`` recording's tilt (fitted
  together, ``joint.py``); ``fit_free_load(dataset, leg, settings) -> FreeLoadResult`` (one, alone).
* :class:`FreeLoadResult` (``result.py``): results protocol (``params``, ``bse``, ``cov_params()``,
  ``conf_int()``, ``summary()``), ``identifiability()`` (what the data leave undetermined, which
  combinations they determine), ``load_report()`` (the ``calibration.json`` keys of the load),
  ``predict(gravity_B, q)`` / ``predict_recording(rec, g)`` (model readings of any sample), ``offset``,
  ``theta``, ``rotation`` (``E``), ``tilt`` (the world tilt), ``recording_tilts`` (recording -> tilt), ``sigma``,
  ``rms``, ``selection`` (kept / dropped per recording, thresholds), ``used`` (recording -> boolean mask of the
  samples the fit used).

Modules: ``quasistatic`` (sample selection), ``problem`` (data, exact compression), ``nlp`` (CasADi/IPOPT),
``estimate`` (the fit), ``joint`` (transducers sharing a recording's tilt, fitted together), ``result`` (results
protocol).

Model (``loads.base``): ``f = M E^T b + f_o``, ``t = (K theta) x (E^T b) + t_o``, ``b = R_nom^T g_B`` the
nominal gravity in ft for each sample (``R_nom`` from ``robot.toml`` or from the URDF for the sample's joint
angles), ``E`` the mounting rotation (``R_true = R_nom E``, exact SO(3)), ``theta`` the load's parameters
(mass and first moment per rigid group: linear in the readings). Steps:

1. quasi-static samples of each recording in which the load hangs free (``quasistatic.py``; counts logged);
2. the exact compression of the samples into channel moments (``problem.py``: no loop over samples), per tilt group;
3. a start by linear least squares with ``E = I``; then the NLP with exact SO(3) (``nlp.py``), weighted by
   the readings' noise (first differences), re-weighted once by the residual sd per channel; what the data
   leave undetermined stays at the load's prior (the URDF's values; ``E = I``), nothing else does;
4. Gauss-Newton information ``J^T Q_W J`` in local coordinates (``E = E* (I + [delta]x)``), the weights
   shrunk where the residuals are serially correlated (AR(1) variance inflation, at most the samples per
   hold: ``problem.serial_inflation``; white noise leaves them), its scaled
   eigen-analysis (``solver.identifiability``): covariance on the determined subspace, ``bse`` inf for
   parameters in undetermined directions, those directions named, and the determined combinations of the
   parameters they touch given with se (reduced row echelon form: for ``shared/sample_urdf`` the total mass,
   the sum of the three bodies' y first moments, ...).

World tilt (``FreeLoadSettings.gravity_tilt``, on by default): a tilt ``R_t = R_y(ty) R_x(tx)`` of the orientation
stream's world (a turn about vertical is unobservable) gives gravity in ft ``E^T R_nom^T R_WB^T u``,
``u = R_t (0, 0, -1)``: it sits on the world side of the varying ``R_WB``, so it is NOT a mounting rotation, and is
separable from ``E`` whenever the orientations are not all about one axis. With ``b_n = A_n u`` (``A_n = g R_nom^T
R_WB^T``) every feature is linear in ``u``: the lifted vector ``[w_o; u (x) z_r]`` (``problem.compress_tilted``)
keeps the compression exact for any tilt. Estimated (parameters ``{leg}.tilt.rx, .ry`` in rad, between the load's
and the mount's; ``calibration.json`` ``gravity_tilt_rad``) from the recordings that give the orientation per sample
(quaternions); where gravity spans fewer than three directions in ft (or the eigen-analysis finds the tilt in an
undetermined direction) it is held at 0, named undetermined (se inf) with a note. A 1 deg / 0.5 deg tilt left out
biases the fit beyond 4 se (``tests/test_freeload_tilt.py``). ``correct`` and ``export`` apply it to ``qw..qz``
(not to ``gx..gz``: an accelerometer's gravity), ``plan`` and the accuracy bench bound it.

Tilt per recording (``FreeLoadSettings.recording_tilt``, ``"auto"`` by default; the hexapod model's hanging
misalignment per orientation): a recording that gives gravity by ``gravity_body`` only has ``b_n = g R_nom^T F_r
u_r``, ``F_r`` a frame whose ``(0, 0, -1)`` is the nominal direction (``problem.gravity_frame``), ``u_r =
R_y(ty) R_x(tx) (0, 0, -1)``: two parameters ``{leg}.{recording}.tilt.rx, .ry`` (``recording_tilt_rad``) and the
same exact lifting, one ``u_r`` block per recording: the samples are compressed per tilt group (the world's, each
such recording's, the ``gx..gz`` recordings' fixed one) and the NLP sums the groups' squares
(``nlp.FreeLoadNLP``, ``G`` groups). For one transducer whose every gravity direction comes from ``gravity_body``,
the tilts and the mounting rotation absorb one another (each recording's gravity in ft is free; the same holds for
several transducers fitted apart, and would hold for a joint fit up to a common turn of the body): ``"auto"`` finds
the undetermined directions only the tilts create (``estimate._recording_tilts_held``), holds those recordings'
tilts at 0 (taken as exact, not reported) and says so in a note naming them. They are determined where something
else fixes the mount (a recording with the orientation per sample or ``gx..gz``, or ``mount_rotation = false``):
then a 0.5-1 deg tilt per recording is recovered within 4 se and leaving it out biases
the fit beyond 4 se (``tests/test_freeload_recording_tilt.py``). ``true`` estimates them regardless (the gauge then
named undetermined), ``false`` takes them as exact with a note. The tilt is the body's: ``fit_free_loads`` fits the
transducers that hang free in a common such recording together (``joint.py``: one NLP, the tilts and the world tilt
shared, each transducer's result its block of the joint covariance; a transducer without recordings of its own
that fix its mount gets it through the shared tilts); ``fit_free_load`` fits one transducer alone. With every
gravity direction from ``gravity_body`` and the mounts free, a common turn of the body stays undetermined (the
tilts are then held, as for one transducer). The covariance file keeps each transducer's block (the shared tilts
under each transducer's name; their correlation across transducers is not written).
"""

from __future__ import annotations

from .estimate import fit_free_load, free_load_calibration, free_load_data
from .shared_tilt import fit_free_loads
from .problem import FreeLoadData
from .result import FreeLoadResult, FreeLoadResults

__all__ = ["fit_free_loads", "fit_free_load", "free_load_data", "free_load_calibration", "FreeLoadResult", "FreeLoadResults",
           "FreeLoadData"]
