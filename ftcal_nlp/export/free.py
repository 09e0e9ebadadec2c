"""``export`` for free loads (``DATA_FORMAT.md`` section 5): per transducer the contact wrench as C.

A calibration whose transducers carry free loads (``load_kind`` ``rigid_payload`` or ``urdf_subtree``). One call per
sample, all transducers at once, the calibration's numbers baked in as constants; it computes what ``correct``
writes (``correct/free.py``): for every transducer k

    g_B,k = g R_WB^T u_k                                        gravity in B from the body's orientation
    g_k = (R_nom,k(q) E_k)^T g_B,k                              gravity in the (estimated true) ft_k frame
    w_c,k = C_k (w_m,k - w_o,k) - [M_k g_k ; s_k(q) x g_k]     contact wrench in ft_k, about its origin

with ``u_k = R_y(ty) R_x(tx) (0, 0, -1)`` the world tilt of the orientation stream transducer k's calibration
estimated (``gravity_tilt_rad``; ``(0, 0, -1)`` without one), for a rigid payload, ``R_nom`` the robot's nominal rotation
(on an arm whose URDF leaves the tool out, ``R_nom(q)`` the URDF's sensor pose as below), ``M = m`` and ``s = h = m c``; for a URDF
load, ``R_nom(q)`` the URDF's sensor pose for the joints above it and ``s(q) = sum_G M_G p_G(q) + R_G(q) H_G``
over the groups of links below it (``loads.urdf_subtree``), the joint transforms written symbolically
(``loads.urdf_subtree.symbolic_pose``: ``T_origin [exp(q [a]x), 0; 0, 1]`` revolute/continuous,
``T_origin [I, q a; 0, 1]`` prismatic, Rodrigues' formula for the exponential) as ``kinematics.py`` does
numerically; each calibrated load writes its own (``loads.calibrated``: ``symbolic_load``). ``C_k`` is the sensor
matrix the calibration refitted in situ (``sensor_matrix`` of ``calibration.json``, ``estimate/freeload/sensor_matrix.py``:
``C (r - o) = w``); without one, or the identity, the expression is ``w_m,k - w_o,k - ...`` as written before the
matrix existed (the same generated source). The standard errors are not exported (a controller wants the wrench;
``correct`` gives the se).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from ..core.errors import DataFormatError
from ..estimate.freeload.problem import tilt_gravity
from ..core.geometry import quat_to_rotation

if TYPE_CHECKING:
    from . import BatchCall


def joint_order(cals: dict) -> tuple[str, ...]:
    """The joints the correction reads, in the order of its ``q`` argument (each transducer's, first seen first)."""
    out: list[str] = []
    for c in cals.values():
        out += [j for j in getattr(c, "joints", ()) if j not in out]
    return tuple(out)


def correction_function(cals: dict, name: str) -> ca.Function:
    """CasADi Function ``(wrench[6K], quat[4]) -> contact[6K]`` (payloads only) or
    ``(wrench[6K], q[J], quat[4]) -> contact[6K]`` (module docstring), ``cals`` the calibrated loads
    (``loads.calibrated``) by transducer (their order is the argument order)."""
    legs = list(cals)
    K = len(legs)
    joints = joint_order(cals)
    w = ca.MX.sym("wrench", 6 * K)
    qv = ca.MX.sym("q", len(joints))
    quat = ca.MX.sym("quat", 4)
    qd = {j: qv[i] for i, j in enumerate(joints)}
    g = next(iter(cals.values())).g
    R_WB = quat_to_rotation(quat)
    out = []
    for i, k in enumerate(legs):
        c = cals[k]
        tilt = getattr(c, "tilt", None)
        u = ca.DM([0.0, 0.0, -1.0]) if tilt is None else ca.DM(tilt_gravity(tilt))
        g_B = g * ca.mtimes(R_WB.T, u)
        R, s, M = c.symbolic_load(qd)   # the ft orientation in B, the first moment and the mass (the load's own)
        g_k = ca.mtimes(R.T, g_B)
        load_w = ca.vertcat(M * g_k, ca.cross(s, g_k))
        C = getattr(c, "sensor_matrix", None)
        if C is None:   # the factory matrix: the expression (and the generated source) as without the in-situ matrix
            out.append(w[6 * i: 6 * i + 6] - ca.DM(c.offset) - load_w)
        else:
            out.append(ca.mtimes(ca.DM(C), w[6 * i: 6 * i + 6] - ca.DM(c.offset)) - load_w)
    contact = ca.vertcat(*out)
    if joints:
        return ca.Function(name, [w, qv, quat], [contact], ["wrench", "q", "quat"], ["contact"])
    return ca.Function(name, [w, quat], [contact], ["wrench", "quat"], ["contact"])


def wrapper_source(f: ca.Function, name: str, cals: dict) -> tuple[str, str]:
    """Plain-array entry points (stack work arrays, reentrant) and a batch loop over samples."""
    K, J = len(cals), len(joint_order(cals))
    qa, qp, qc, qb = (", const casadi_real* q", "q, ", f"q + {J} * i, ", ", const casadi_real* q") if J else ("", "", "", "")
    src = f"""
/* Plain-array entry points (ftcal_nlp.export, free loads): no allocation, reentrant. */
int {name}_sample(const casadi_real* wrench{qa}, const casadi_real* quat, casadi_real* contact_out) {{
  const casadi_real* arg[{max(f.sz_arg(), 3)}] = {{wrench, {qp}quat}};
  casadi_real* res[{max(f.sz_res(), 1)}] = {{contact_out}};
  casadi_int iw[{max(f.sz_iw(), 1)}];
  casadi_real w[{max(f.sz_w(), 1)}];
  return {name}(arg, res, iw, w, 0);
}}

int {name}_batch(long n, const casadi_real* wrench{qb}, const casadi_real* quat, casadi_real* contact_out) {{
  long i;
  for (i = 0; i < n; ++i) {{
    int flag = {name}_sample(wrench + {6 * K} * i, {qc}quat + 4 * i, contact_out + {6 * K} * i);
    if (flag) return flag;
  }}
  return 0;
}}
"""
    hdr = f"""
/* Plain-array entry points (ftcal_nlp.export, free loads), see USAGE.md. */
#ifdef __cplusplus
extern "C" {{
#endif
#define {name.upper()}_N_TRANSDUCERS {K}
#define {name.upper()}_N_JOINTS {J}
int {name}_sample(const casadi_real* wrench{qa}, const casadi_real* quat, casadi_real* contact_out);
int {name}_batch(long n, const casadi_real* wrench{qb}, const casadi_real* quat, casadi_real* contact_out);
#ifdef __cplusplus
}}
#endif
"""
    return src, hdr


def base_quaternion(gravity_body: np.ndarray) -> np.ndarray:
    """``qw..qz`` of the smallest rotation ``R_WB`` that puts gravity along ``gravity_body`` in B
    (``R_WB^T (0, 0, -1) = gravity_body``): the orientation to pass for a fixed base."""
    from ..core.geometry import rotation_to_quat, rotvec_to_rotation

    a = np.asarray(gravity_body, float) / np.linalg.norm(gravity_body)
    b = np.array([0.0, 0.0, -1.0])
    axis, c = np.cross(a, b), float(np.clip(a @ b, -1.0, 1.0))
    if np.linalg.norm(axis) < 1e-12:
        R = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    else:
        R = rotvec_to_rotation(axis / np.linalg.norm(axis) * np.arccos(c))
    return rotation_to_quat(R)


def _fixed_base_text(cals: dict) -> str:
    """USAGE.md's paragraph for a fixed base (the calibration keeps its ``gravity_body``): the constant ``quat``."""
    gbs = {k: c.gravity_body for k, c in cals.items() if getattr(c, "gravity_body", None) is not None}
    if not gbs or len(gbs) < len(cals):
        return ""
    k, gb = next(iter(gbs.items()))
    qb = base_quaternion(gb)
    return (f"\nA fixed base (an arm logging joints only): pass `quat` = `{' '.join(f'{v:.17g}' for v in qb)}` for every "
            f"sample, the base's orientation that puts gravity along the calibration's `gravity_body` "
            f"{np.round(gb, 9).tolist()} (of `{k}`; `correct` uses the same for a recording without orientation columns).\n")


def usage_note(cals: dict, name: str, source: str) -> str:
    """The one-page usage note (USAGE.md) of an exported free-load correction."""
    legs = list(cals)
    K = len(legs)
    joints = joint_order(cals)
    J = len(joints)
    cols = ", ".join(f"`{k}`" for k in legs)
    kinds = ", ".join(f"`{k}` ({c.describe()})" for k, c in cals.items())
    fixed = _fixed_base_text(cals)
    with_c = [k for k, c in cals.items() if getattr(c, "sensor_matrix", None) is not None]
    mat = (f"For {', '.join(f'`{k}`' for k in with_c)} the readings less the offset are first mapped by the sensor matrix the "
           "calibration refitted in situ (`sensor_matrix`, C): contact = C (reading - offset) - load.\n") if with_c else ""
    q_sig = "const double* q, " if J else ""
    q_row = (f"| `q` | {J} | joint angles, in this order: {', '.join(f'`{j}`' for j in joints)} | rad (m for prismatic) | URDF |\n"
             if J else "")
    return f"""# `{name}`: contact wrenches of free loads in C

Generated by `python -m ftcal_nlp.export` (CasADi {getattr(ca, '__version__', '?')}) from `{source}`
({K} transducer(s): {kinds}). The calibration's numbers are compiled in; re-export after every calibration.

## Signature

```c
#include "{name}.h"
int {name}_sample(const double* wrench, {q_sig}const double* quat, double* contact);   /* one sample */
int {name}_batch(long n, const double* wrench, {q_sig}const double* quat, double* contact);  /* n samples */
```

Both return 0 on success; they allocate nothing and keep no state (real-time and thread safe).

| argument | length | content | unit | frame |
|---|---|---|---|---|
| `wrench` | {6 * K} | raw readings, transducer after transducer ({cols}), each `fx fy fz tx ty tz` | N, N*m | each transducer's frame, about its origin |
{q_row}| `quat` | 4 | `qw qx qy qz` of the body B in the world (normalised inside) | - | |
| `contact` (out) | {6 * K} | contact wrench: reading less offset less the load's weight wrench, same order | N, N*m | the transducer's (estimated true) frame, about its origin |

While the load touches nothing, `contact` is zero within the sensor noise. This is what
`python -m ftcal_nlp.correct` writes for the same calibration (without its se columns), to rounding.
A NaN quaternion gives NaN outputs (`correct` drops such rows).
{mat}{fixed}
## Build

```bash
cc -O2 -fPIC -shared {name}.c -o lib{name}.so -lm
```
"""


def check(cals: dict, source: str) -> None:
    """A calibration with named effects (``calibration_with_effect.json``) is an error: the C function is the
    per-sample load model, the effects' corrections need a recording's history (``effects/correction.py``)."""
    named = {k: [m.name for m in c.effects.members] for k, c in cals.items() if getattr(c, "effects", None) is not None}
    if named:
        raise DataFormatError(f"{source}: meta.effect names {named}: export compiles the per-sample load model only, and "
                              "these effects' corrections need each recording's history (re-sampling, relaxation filters, "
                              "the session's clock); `correct` applies them. Export the run's calibration.json for the "
                              "load model alone", path=source, column="meta.effect")


def load_compiled(lib: str | Path, cals: dict, name: str) -> "BatchCall":
    """numpy front of a compiled free-load correction: ``(wrench (N, K, 6), q (N, J) or None, quat (N, 4)) ->
    contact (N, K, 6)``."""
    from . import BatchCall, batch_caller

    K, J = len(cals), len(joint_order(cals))
    call = batch_caller(lib, name, (6 * K, J, 4) if J else (6 * K, 4), ((K, 6),))

    def front(wrench: np.ndarray, q: np.ndarray | None, quat: np.ndarray) -> np.ndarray:
        return call(wrench, q, quat) if J else call(wrench, quat)

    return BatchCall(front, call.lib)
