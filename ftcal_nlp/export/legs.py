"""``export`` for hexapod legs (the ``leg_com_curve`` load): per foot the ground contact wrench as C.

One call per sample, all legs at once, the calibration's numbers baked in as
constants. It computes what :func:`ftcal_nlp.core.physics.ground_wrenches` computes
(and so what ``python -m ftcal_nlp.correct`` writes): for every leg k

    u_k = R_k^T R_WB^T (-z)                                  gravity direction in ft_k
    w_gc,k = w_m,k - w_o,k - [m_k g u_k; r_k(phi_k) x m_k g u_k]   (report eq. 3)
    c = sum_k m_k g (R_k r_k(phi_k) + p'_k) / (M g)          total CoM in B
    w_H,k = [R_HB R_k f; R_HB R_k tau + R_HB (p'_k - c) x R_HB R_k f]

with ``R_HB = Rz(-yaw) R_WB`` the heading frame (``OUTPUT_FORMAT.md``) and
``r_k(phi)`` the calibration's CoM grid interpolated linearly and periodically
(as :meth:`ftcal_nlp.core.calibration.LegCalibration.com`). The symbolic twin is
checked against the numpy path to 1e-12 in the tests.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import casadi as ca
import numpy as np

from ..core.calibration import Calibration, LegCalibration
from ..core.errors import DataFormatError
from ..core.geometry import cross, quat_to_rotation, remove_yaw, transform_wrench


def _com_interpolant(leg: LegCalibration, name: str) -> Callable[[ca.MX], ca.MX]:
    """Symbolic ``r_k(phi)`` (3-vector, m, ft_k): periodic linear interpolation of the grid,
    the same as ``periodic_interp`` (np.interp: held constant outside the extended grid)."""
    if not np.all(np.isfinite(leg.com_xyz)):
        bad = np.flatnonzero(~np.all(np.isfinite(leg.com_xyz), axis=1))
        raise DataFormatError(f"{name}: leg_com_grid.xyz has no value at grid points {bad.tolist()}; a controller needs a CoM at every shaft angle")
    xp = np.concatenate([leg.com_phi, [leg.com_phi[0] + 2 * np.pi]])
    fp = np.concatenate([leg.com_xyz, leg.com_xyz[:1]])
    if np.any(np.diff(xp) <= 0):
        raise DataFormatError(f"{name}: leg_com_grid.phi must increase within [0, 2pi)")
    interp = ca.interpolant(name, "linear", [xp], fp.ravel())  # output index fastest

    def r(phi: ca.MX) -> ca.MX:
        x = phi - 2 * np.pi * ca.floor(phi / (2 * np.pi))
        return interp(ca.fmin(ca.fmax(x, xp[0]), xp[-1]))

    return r


def correction_function(cal: Calibration, name: str) -> ca.Function:
    """CasADi Function ``(wrench[6K], phi[K], quat[4]) -> (ground[6K], total[6])`` of one sample.

    ``wrench``: readings, leg after leg in the calibration's leg order, each
    ``fx fy fz tx ty tz`` (N, N*m, ft_k); ``phi``: shaft angles (rad, unwrapped
    or not); ``quat``: ``qw qx qy qz`` of B in the world (normalised inside).
    ``ground``: ground contact wrench on each foot in the heading frame, torques
    about the robot's CoM, same order; ``total``: their sum.
    """
    legs = cal.leg_names
    K = len(legs)
    offsets, weights, rotations, p_prime = cal.stacked()
    w = ca.MX.sym("wrench", 6 * K)
    phi = ca.MX.sym("phi", K)
    q = ca.MX.sym("quat", 4)
    R_WB = quat_to_rotation(q)
    R_HB = remove_yaw(R_WB)
    u_B = -R_WB[2, :].T
    r = [_com_interpolant(cal.legs[k], f"{name}_com_{k}")(phi[i]) for i, k in enumerate(legs)]
    c_tot = sum(weights[i] * (ca.mtimes(ca.DM(rotations[i]), r[i]) + ca.DM(p_prime[i])) for i in range(K)) / (cal.mass_kg * cal.g)
    ground = []
    for i in range(K):
        R_k = ca.DM(rotations[i])
        f_leg = weights[i] * ca.mtimes(R_k.T, u_B)
        w_gc = w[6 * i : 6 * i + 6] - ca.DM(offsets[i]) - ca.vertcat(f_leg, cross(r[i], f_leg))
        ground.append(transform_wrench(ca.mtimes(R_HB, R_k), ca.mtimes(R_HB, ca.DM(p_prime[i]) - c_tot), w_gc))
    total = sum(ground[1:], ground[0])
    return ca.Function(name, [w, phi, q], [ca.vertcat(*ground), total], ["wrench", "phi", "quat"], ["ground", "total"])


def wrapper_source(f: ca.Function, name: str, cal: Calibration) -> tuple[str, str]:
    """A plain-array entry point (stack work arrays, so reentrant) and a batch loop over samples."""
    K = len(cal.leg_names)
    src = f"""
/* Plain-array entry points (ftcal_nlp.export): no allocation, reentrant. */
int {name}_sample(const casadi_real* wrench, const casadi_real* phi, const casadi_real* quat,
                  casadi_real* ground, casadi_real* total) {{
  const casadi_real* arg[{max(f.sz_arg(), 3)}] = {{wrench, phi, quat}};
  casadi_real* res[{max(f.sz_res(), 2)}] = {{ground, total}};
  casadi_int iw[{max(f.sz_iw(), 1)}];
  casadi_real w[{max(f.sz_w(), 1)}];
  return {name}(arg, res, iw, w, 0);
}}

int {name}_batch(long n, const casadi_real* wrench, const casadi_real* phi, const casadi_real* quat,
                 casadi_real* ground, casadi_real* total) {{
  long i;
  for (i = 0; i < n; ++i) {{
    int flag = {name}_sample(wrench + {6 * K} * i, phi + {K} * i, quat + 4 * i, ground + {6 * K} * i, total + 6 * i);
    if (flag) return flag;
  }}
  return 0;
}}
"""
    hdr = f"""
/* Plain-array entry points (ftcal_nlp.export), see USAGE.md. */
#ifdef __cplusplus
extern "C" {{
#endif
#define {name.upper()}_N_LEGS {K}
int {name}_sample(const casadi_real* wrench, const casadi_real* phi, const casadi_real* quat,
                  casadi_real* ground, casadi_real* total);
int {name}_batch(long n, const casadi_real* wrench, const casadi_real* phi, const casadi_real* quat,
                 casadi_real* ground, casadi_real* total);
#ifdef __cplusplus
}}
#endif
"""
    return src, hdr


def usage_note(cal: Calibration, name: str, source: str = "calibration.json") -> str:
    """The one-page usage note (USAGE.md) of an exported correction."""
    legs = cal.leg_names
    K = len(legs)
    cols = ", ".join(f"`{k}`" for k in legs)
    return f"""# `{name}`: per-foot ground contact wrenches in C

Generated by `python -m ftcal_nlp.export` (CasADi {getattr(ca, '__version__', '?')}) from `{source}`
(model `{cal.model}`, {K} legs: {cols}). The calibration's numbers are compiled in;
re-export after every calibration.

## Signature

```c
#include "{name}.h"
int {name}_sample(const double* wrench, const double* phi, const double* quat,
                  double* ground, double* total);           /* one sample, all legs */
int {name}_batch(long n, const double* wrench, const double* phi, const double* quat,
                 double* ground, double* total);            /* n samples, rows back to back */
```

Both return 0 on success. They allocate nothing and keep no state (work arrays on the
stack): safe to call from a real-time loop and from several threads. The CasADi-standard
entry `{name}(arg, res, iw, w, mem)` with `{name}_work` is there too.

| argument | length | content | unit | frame |
|---|---|---|---|---|
| `wrench` | {6 * K} | raw readings, leg after leg ({cols}), each `fx fy fz tx ty tz` | N, N*m | each leg's transducer frame ft_k, about its origin |
| `phi` | {K} | motor shaft angle per leg, same order (0 = leg straight down; wrapped or unwrapped) | rad | |
| `quat` | 4 | `qw qx qy qz` of the body in the world (maps body vectors to world vectors; normalised inside) | - | |
| `ground` (out) | {6 * K} | ground contact wrench on each foot, same order, `fx fy fz tx ty tz` | N, N*m | heading frame |
| `total` (out) | 6 | sum over the feet | N, N*m | heading frame |

Heading frame: origin at the robot's CoM at that instant (body and legs, from the
calibration and the shaft angles), z up against gravity, x the body's x axis projected
on the horizontal plane; torques are about that CoM. Standing still, `total` is
`[0, 0, {cal.mass_kg * cal.g:.6g}, 0, 0, 0]` (the robot's weight, N); a foot in the air reads zero.
This is what `python -m ftcal_nlp.correct` writes (`OUTPUT_FORMAT.md`), to rounding. Without a
motion-capture orientation (NaN quaternion) the outputs are NaN: `correct` drops such rows.
The leg CoM curves are interpolated linearly on the calibration's periodic grid.

## Build

```bash
cc -O2 -fPIC -shared {name}.c -o lib{name}.so -lm     # shared library
cc -O2 -c {name}.c -o {name}.o                         # or link the object into the controller
```

From Python: `ftcal_nlp.export.compile_shared(DIR)` and `load_compiled(...)` do the same
and give a numpy function `(wrench (N, K, 6), phi (N, K), quat (N, 4)) -> (N, K, 6)`.
"""


def check(cal: Calibration, source: str) -> None:
    """Nothing beyond the reader's checks (a leg's CoM grid is checked as its interpolant is built)."""


def load_compiled(lib: str | Path, cal: Calibration, name: str) -> Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
    """numpy front of a compiled correction: ``(wrench (N,K,6), phi (N,K), quat (N,4)) -> ground (N,K,6)``."""
    from . import batch_caller

    K = len(cal.leg_names)
    return batch_caller(lib, name, (6 * K, K, 4), ((K, 6), (6,)))
