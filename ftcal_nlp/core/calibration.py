"""The calibration: everything a correction needs, as in ``shared/OUTPUT_FORMAT.md``.

Per leg k: the transducer offset ``w_o`` (report eq. 1, in ft_k), the leg weight
``m_k g``, the leg CoM curve ``r_k(phi)`` in ft_k on a periodic grid, the
rotation ``R_k = R_ftk^B`` (nominal rotation times the mounting error
``R_tilde``) and ``p_prime_k``, the origin of ft_k relative to the CoM of the
body without legs, in B axes (the report's ``p'_k`` up to that choice of
reference point). ``com_body_m`` is that CoM in B, or None where the data
cannot place it (models that free every transducer translation).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .data import G_RANGE, DataFormatError


@dataclass(frozen=True)
class LegCalibration:
    offset: np.ndarray                 # (6,) N, N*m in ft_k
    leg_weight_N: float
    com_phi: np.ndarray                # (G,) rad in [0, 2pi), increasing
    com_xyz: np.ndarray                # (G, 3) m in ft_k; NaN where unsupported by data
    rotation_to_body: np.ndarray       # (3, 3) ft_k -> B
    position_from_com_m: np.ndarray    # (3,) m, B axes, relative to body-without-legs CoM
    offset_se: np.ndarray | None = None
    leg_weight_se_N: float | None = None
    position_from_com_se_m: np.ndarray | None = None
    com_xyz_se: np.ndarray | None = None
    rotation_se_rad: np.ndarray | None = None   # se of the rotation vector of R_k (left perturbation, B axes)
    load: dict | None = None           # a free load's calibration.json keys (DATA_FORMAT.md section 5, freeload)

    def com(self, phi: np.ndarray) -> np.ndarray:
        """Leg CoM ``r_k(phi)`` in ft_k, (N, 3) m, by periodic linear interpolation of the grid."""
        return periodic_interp(np.asarray(phi, float), self.com_phi, self.com_xyz)


def periodic_interp(phi: np.ndarray, grid: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Interpolate ``values`` (G, d) given on the periodic ``grid`` (G,) at ``phi`` (any shape).

    ``np.interp`` on the grid extended by one period (held at ``values[0]`` below
    the first point). Several curves on one grid: ``values`` (K, G, d) and ``phi``
    (..., K) give (..., K, d), curve k at ``phi[..., k]``. On a uniform grid from 0
    with finite values (the calibration's CoM grids) the interval and the fraction
    ``t`` come straight from ``phi G / 2pi`` and one gather of (value, difference)
    serves all columns: ``fp[j] + t (fp[j+1] - fp[j])``, equal to np.interp to rounding.
    :class:`PeriodicInterpolator` prepares the grid once for many calls.
    """
    return PeriodicInterpolator(grid, values)(phi)


class PeriodicInterpolator:
    """:func:`periodic_interp` with the grid's tables formed once (a caller evaluating block after block)."""

    def __init__(self, grid: np.ndarray, values: np.ndarray):
        G, d = values.shape[-2:]
        self.G, self.d, self.multi = G, d, values.ndim == 3
        self.xp = np.concatenate([grid, [grid[0] + 2 * np.pi]])
        self.fp = np.concatenate([values, values[..., :1, :]], axis=-2)
        self.step = np.diff(self.xp)
        self.fast = bool(grid[0] == 0 and np.allclose(self.step, self.step[0], rtol=1e-12, atol=0) and np.all(np.isfinite(values)))
        if self.fast:
            table = np.concatenate([self.fp[..., :-1, :], np.diff(self.fp, axis=-2)], axis=-1)  # (.., G, 2d)
            self.table = table.reshape(-1, 2 * d)
            self.offset = G * np.arange(values.shape[0]) if self.multi else 0
        else:
            with np.errstate(invalid="ignore"):
                self.slope = np.diff(self.fp, axis=-2) / self.step[:, None]
            self.k = (np.arange(values.shape[0]),) if self.multi else ()

    def __call__(self, phi: np.ndarray) -> np.ndarray:
        G, d = self.G, self.d
        if self.fast:
            y = np.asarray(phi, float) * (G / (2 * np.pi))
            fl = np.floor(y)
            t = (y - fl)[..., None]
            with np.errstate(invalid="ignore"):  # a NaN angle takes any interval; t keeps it NaN
                j = fl.astype(np.intp) % G
            row = np.take(self.table, j + self.offset, axis=0)
            return row[..., :d] + row[..., d:] * t
        xp, fp, k = self.xp, self.fp, self.k
        x = np.maximum(np.mod(phi, 2 * np.pi), xp[0])
        j = np.minimum(np.searchsorted(xp, x, side="right") - 1, G - 1)
        dx = (x - xp[j])[..., None]
        out = fp[k + (j,)] + self.slope[k + (j,)] * dx
        # on a grid point next to a missing value: that point's value, as np.interp
        return np.where(dx == 0, fp[k + (j,)], out)


def interp_cells(phi: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cells of :func:`periodic_interp` at ``phi`` (N,): grid indices ``i0``, ``i1`` (N,) and the weight
    ``a`` (N,) of ``i1`` (value = (1 - a) v[i0] + a v[i1])."""
    G = len(grid)
    x = np.mod(phi, 2 * np.pi)
    xp = np.concatenate([grid, [grid[0] + 2 * np.pi]])
    i = np.clip(np.searchsorted(xp, x, side="right") - 1, 0, G - 1)
    a = np.clip((x - xp[i]) / (xp[i + 1] - xp[i]), 0.0, 1.0)  # np.interp holds the first value below grid[0]
    return i, (i + 1) % G, a


def _nulls(x):
    """Nested lists / dicts with non-finite floats replaced by None (strict JSON); other values as they are."""
    if isinstance(x, (list, tuple)):
        return [_nulls(v) for v in x]
    if isinstance(x, dict):
        return {k: _nulls(v) for k, v in x.items()}
    if isinstance(x, np.ndarray):
        return _nulls(x.tolist())
    if isinstance(x, (float, np.floating)):
        return float(x) if np.isfinite(x) else None
    return x


def _design_rotation(load: dict) -> dict:
    """``rotation_nominal``, the design rotation ft -> B of a free load stored with both ``rotation_to_body`` and
    ``mount_rotation`` (``R_B,ft = R_nom E``): with it a reader checks that the copies of the mount agree. A load
    oriented through a URDF (``urdf``, ``link``; no ``rotation_to_body``) stores the URDF's pose of the sensor link
    at zero joint angles: with it a reader checks that the URDF it parses is the one calibrated with."""
    if "rotation_nominal" in load:
        return {}
    if load.get("rotation_to_body") is None and load.get("urdf") is not None and load.get("link") is not None:
        try:
            return {"rotation_nominal": _nulls(urdf_rotation_at_zero(Path(load["urdf"]), str(load["link"]), "calibration"))}
        except (DataFormatError, KeyError):   # the URDF not where the entry names it (a copy): nothing to keep
            return {}
    if load.get("rotation_to_body") is None or load.get("mount_rotation") is None:
        return {}
    R, E = np.asarray(load["rotation_to_body"], float), np.asarray(load["mount_rotation"], float)
    return {"rotation_nominal": _nulls(R @ E.T)}


def urdf_rotation_at_zero(urdf: Path, link: str, where: str, tree=None) -> np.ndarray:
    """The URDF's nominal rotation ft -> B of sensor ``link`` with every joint at 0 (``tree``: the URDF parsed)."""
    from .data import read_urdf_tree

    tree = read_urdf_tree(urdf, where) if tree is None else tree
    return tree.pose(tree.root, link, {}, 1)[0][0]


#: Candidates of the report's Table I, in its order (the standing error models' names).
REPORT_CANDIDATES: tuple[str, ...] = ("full", "rot6_trans1", "trans6", "trans1")


class ModelName(str):
    """A calibration's ``model`` as read from a file: a name for the error-model registry only.

    :func:`ftcal_nlp.models.resolve` never imports code for one (a ``"file.py:Class"`` received in a
    ``calibration.json`` is refused, not run). ``str()`` keeps the mark, so the name stays marked when a
    run copies it into its own result (offsets-only re-estimation)."""

    __slots__ = ()

    def __str__(self) -> "ModelName":
        return self


@dataclass(frozen=True)
class Calibration:
    """A finished (or true) calibration of a robot; serialised as ``calibration.json``."""

    legs: dict[str, LegCalibration]
    mass_kg: float
    g: float
    model: str = "full"
    com_body_m: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    @property
    def leg_names(self) -> tuple[str, ...]:
        return tuple(self.legs)

    @property
    def body_weight_N(self) -> float:
        """Weight of the body without legs: weighed total less the leg weights."""
        return self.mass_kg * self.g - sum(l.leg_weight_N for l in self.legs.values())

    def stacked(self, legs=None):
        """(offsets (K,6), leg weights (K,), rotations (K,3,3), positions (K,3)) in leg order."""
        legs = self.leg_names if legs is None else legs
        L = [self.legs[k] for k in legs]
        return (
            np.stack([l.offset for l in L]),
            np.array([l.leg_weight_N for l in L]),
            np.stack([l.rotation_to_body for l in L]),
            np.stack([l.position_from_com_m for l in L]),
        )

    def leg_coms(self, phi: np.ndarray) -> np.ndarray:
        """Every leg's CoM ``r_k(phi_k)`` in its ft_k, (N, K, 3) m, from shaft angles ``phi`` (N, K) in leg order."""
        return self.leg_com_interpolator()(phi)

    def leg_com_interpolator(self, in_body: bool = False):
        """``phi`` (N, K) -> every leg's CoM (N, K, 3) m, the grids' tables formed once; ``in_body``: in B about the
        body-without-legs CoM, ``R_k r_k + p'_k`` (interpolated from the grid turned into B: linear interpolation
        commutes with the affine map, equal to turning the interpolated CoM to rounding)."""
        L = list(self.legs.values())
        if in_body:
            _, _, R, p = self.stacked()
            xyz = [l.com_xyz @ R[i].T + p[i] for i, l in enumerate(L)]
        else:
            xyz = [l.com_xyz for l in L]
        if all(np.array_equal(l.com_phi, L[0].com_phi) for l in L):  # one grid: all legs in one pass
            one = PeriodicInterpolator(L[0].com_phi, np.stack(xyz))
            return lambda phi: one(np.asarray(phi, float))
        each = [PeriodicInterpolator(l.com_phi, v) for l, v in zip(L, xyz)]
        return lambda phi: np.stack([f(np.asarray(phi, float)[:, i]) for i, f in enumerate(each)], axis=1)

    def to_json_dict(self) -> dict:
        def lst(a):
            # strict JSON has no NaN/inf: a value the data do not determine is written as null
            if a is None:
                return None
            a = np.asarray(a, dtype=float)
            return None if a.ndim == 0 and not np.isfinite(a) else _nulls(a.tolist())

        legs = {}
        for k, l in self.legs.items():
            if l.load is not None:  # a free load: offsets and the load's keys (OUTPUT_FORMAT.md), no hexapod keys
                # no leg_weight_N: "keys of the hexapod layout appear where they apply, and only there" (OUTPUT_FORMAT.md);
                # the load's weight is load_mass_kg times g
                legs[k] = {"offset": lst(l.offset), "offset_se": lst(l.offset_se), **_nulls(l.load), **_design_rotation(l.load)}
                continue
            d = {
                "offset": lst(l.offset),
                "offset_se": lst(l.offset_se),
                "leg_weight_N": float(l.leg_weight_N),
                "leg_weight_se_N": None if l.leg_weight_se_N is None or not np.isfinite(l.leg_weight_se_N) else float(l.leg_weight_se_N),
                "leg_com_grid": {"phi": lst(l.com_phi), "xyz": lst(l.com_xyz)},
                "rotation_to_body": lst(l.rotation_to_body),
                "position_from_com_m": lst(l.position_from_com_m),
                "position_from_com_se_m": lst(l.position_from_com_se_m),
            }
            if l.rotation_se_rad is not None:  # beside the contract's keys, in the same naming
                d["rotation_to_body_se_rad"] = lst(l.rotation_se_rad)
            if l.com_xyz_se is not None:
                d["leg_com_grid"]["xyz_se"] = lst(l.com_xyz_se)
            legs[k] = d
        return {
            "model": self.model,
            "legs": legs,
            "com_body_m": lst(self.com_body_m),
            "mass_kg": None if self.mass_kg is None or not np.isfinite(self.mass_kg) else float(self.mass_kg),
            "g": float(self.g),
            **({"meta": _nulls(self.meta)} if self.meta else {}),
        }

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_json_dict(), indent=1, allow_nan=False))

    @classmethod
    def from_json_dict(cls, d: dict, *, mass_kg: float | None = None, g: float | None = None, source: str = "calibration") -> "Calibration":
        def arr(x, shape=None):
            if x is None:
                return None
            a = np.array([[np.nan if v is None else v for v in r] for r in x] if x and isinstance(x[0], list) else [np.nan if v is None else v for v in x], dtype=float)
            if shape is not None and a.shape != shape:
                raise DataFormatError(f"{source}: expected shape {shape}, got {a.shape}")
            return a

        if "legs" not in d:
            raise DataFormatError(f"{source}: missing key 'legs'")
        legs = {}
        for k, l in d["legs"].items():
            if "load_mass_kg" in l and "leg_com_grid" not in l:  # a free load (section 5)
                legs[k] = LegCalibration(offset=arr(l["offset"], (6,)), leg_weight_N=float(l.get("leg_weight_N", np.nan)),
                                         com_phi=np.zeros(1), com_xyz=arr([l.get("load_com_m") or [np.nan] * 3]),
                                         rotation_to_body=np.eye(3), position_from_com_m=np.zeros(3),
                                         offset_se=arr(l.get("offset_se")), leg_weight_se_N=l.get("leg_weight_se_N"),
                                         load={kk: v for kk, v in l.items() if kk not in ("offset", "offset_se", "leg_weight_N", "leg_weight_se_N")})
                continue
            for key in ("offset", "leg_weight_N", "leg_com_grid", "rotation_to_body", "position_from_com_m"):
                if key not in l:
                    raise DataFormatError(f"{source}: legs.{k} is missing key '{key}'")
            grid = l["leg_com_grid"]
            legs[k] = LegCalibration(
                offset=arr(l["offset"], (6,)),
                leg_weight_N=float(l["leg_weight_N"]),
                com_phi=arr(grid["phi"]),
                com_xyz=arr(grid["xyz"]),
                rotation_to_body=arr(l["rotation_to_body"], (3, 3)),
                position_from_com_m=arr(l["position_from_com_m"], (3,)),
                offset_se=arr(l.get("offset_se")),
                leg_weight_se_N=l.get("leg_weight_se_N"),
                position_from_com_se_m=arr(l.get("position_from_com_se_m")),
                com_xyz_se=arr(grid.get("xyz_se")),
                rotation_se_rad=arr(l.get("rotation_to_body_se_rad")),
            )
        m = d.get("mass_kg", d.get("mass_true_kg", mass_kg))
        gg = d.get("g", g)
        if m is None and legs and all(l.load is not None for l in legs.values()):
            m = np.nan  # free loads only: no robot mass is needed (DATA_FORMAT.md section 5)
        if m is None or gg is None:
            raise DataFormatError(f"{source}: mass_kg and g are needed (in the file or as arguments)")
        com = d.get("com_body_m")
        model = d.get("model", "truth")
        if not isinstance(model, str):
            raise DataFormatError(f"{source}: key 'model' should be a model name (a string), got {model!r}")
        return cls(legs, float(m), float(gg), ModelName(model), None if com is None else arr(com, (3,)), d.get("meta", {}))

    @classmethod
    def load(cls, path: str | Path, **kw) -> "Calibration":
        """Read ``calibration.json`` (:func:`read_calibration_json`: checked as it is read); any fault is a
        :class:`~ftcal_nlp.core.data.DataFormatError` naming the file and the key."""
        return cls.from_checked_dict(read_calibration_json(path), path, **kw)

    @classmethod
    def from_checked_dict(cls, d: dict, path: str | Path, **kw) -> "Calibration":
        """:meth:`from_json_dict` of a dict :func:`read_calibration_json` read from ``path``."""
        try:
            return cls.from_json_dict(d, source=str(path), **kw)
        except DataFormatError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
            raise DataFormatError(f"{path}: not a calibration ({type(exc).__name__}: {exc}); expected the keys of OUTPUT_FORMAT.md",
                                  path=path) from exc


# ----------------------------------------------------------------------------- the one reader of calibration.json

#: orthonormality and determinant of a stored rotation, and agreement of the mounting rotation's copies: the file
#: holds every float to the last bit, so a rotation written by a run is exact to ~1e-15; an edited one is not
ROTATION_TOL = 1e-6
#: the kinds of free load ``correct`` and ``export`` apply (DATA_FORMAT.md section 5)
FREE_LOAD_KINDS = ("rigid_payload", "urdf_subtree")


def read_calibration_json(path: str | Path) -> dict:
    """``calibration.json`` (or ``calibration_with_effect.json``) read and checked: a JSON object with a table
    ``legs``, every number a command applies finite, every rotation proper, one mounting rotation per transducer
    (:func:`check_calibration_dict`). Every command that reads a calibration reads it here."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(f"{path}: calibration file not found", path=path)
    try:
        d = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: not valid JSON ({exc}); expected a calibration.json written by a run (truncated?)",
                              path=path) from exc
    if not isinstance(d, dict):
        raise DataFormatError(f"{path}: expected a JSON object with key 'legs', got {type(d).__name__}", path=path)
    check_calibration_dict(d, str(path))
    return d


def is_free_load(d: dict) -> bool:
    """Whether a checked calibration dict holds free loads (every transducer names its ``load_kind``)."""
    legs = d.get("legs") or {}
    return bool(legs) and all("load_kind" in l for l in legs.values())


def _fail(source: str, key: str, what: str) -> DataFormatError:
    return DataFormatError(f"{source} {key}: {what}", path=source, column=key)


def _numbers(source: str, key: str, v, shape: tuple[int, ...]) -> np.ndarray:
    """``v`` as finite floats of ``shape``, or an error naming ``key`` (a null is how a run writes NaN)."""
    try:
        a = np.array(v, dtype=float)
    except (TypeError, ValueError):
        raise _fail(source, key, f"expected {'x'.join(map(str, shape)) or 'a'} number(s), got {v!r}") from None
    if a.shape != shape:
        raise _fail(source, key, f"expected shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise _fail(source, key, f"holds a null, NaN or infinite value ({_nulls(a.tolist())}); expected finite numbers")
    return a


def _rotation(source: str, key: str, v) -> np.ndarray:
    """A proper rotation matrix (orthonormal, determinant +1, within ``ROTATION_TOL``) or an error naming ``key``."""
    R = _numbers(source, key, v, (3, 3))
    det = float(np.linalg.det(R))
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > ROTATION_TOL or abs(det - 1) > ROTATION_TOL:
        raise _fail(source, key, f"determinant {det:.6g}, max |R^T R - I| {err:.3g}; expected a proper rotation (orthonormal, "
                                 f"det +1, within {ROTATION_TOL:g})")
    return R


def _check_mount(source: str, at: str, l: dict) -> None:
    """One mounting rotation per free-load transducer, read from ``rotation_to_body`` (ft -> B) for a rigid payload
    and from ``mount_rotation`` (``E``) for a URDF load or a payload oriented through the URDF (``link``: its
    nominal pose moves with the joints); the other copies
    must agree with it within ``ROTATION_TOL``: ``mount_rotation = expm([mount_rotvec]x)`` and, where the design
    rotation ``rotation_nominal`` is stored, ``rotation_to_body = rotation_nominal mount_rotation``."""
    from .geometry import rotvec_to_rotation

    read = "rotation_to_body" if l.get("load_kind") == "rigid_payload" and l.get("link") is None else "mount_rotation"
    if l.get(read) is None and (read == "rotation_to_body" or l.get("mount_rotvec") is not None):
        raise _fail(source, f"{at}.{read}", f"missing; the correction reads the {l.get('load_kind')} load's mounting rotation "
                                            "there")
    rot = {k: _rotation(source, f"{at}.{k}", l[k]) for k in ("rotation_to_body", "mount_rotation", "rotation_nominal")
           if l.get(k) is not None}
    if l.get("mount_rotvec") is not None:
        rot["expm([mount_rotvec]x)"] = rotvec_to_rotation(_numbers(source, f"{at}.mount_rotvec", l["mount_rotvec"], (3,)))
    pairs = [("expm([mount_rotvec]x)", "mount_rotation")]
    if "rotation_nominal" in rot:
        rot["rotation_nominal mount_rotation"] = rot["rotation_nominal"] @ rot.get("mount_rotation", np.eye(3))
        pairs.append(("rotation_nominal mount_rotation", "rotation_to_body"))
    for a, b in pairs:
        if a in rot and b in rot and (diff := float(np.abs(rot[a] - rot[b]).max())) > ROTATION_TOL:
            keys = [k for k in ("rotation_to_body", "mount_rotation", "mount_rotvec", "rotation_nominal") if k in a or k == b]
            stored = [k for k in ("rotation_to_body", "mount_rotation", "mount_rotvec") if l.get(k) is not None]
            raise _fail(source, f"{at}.{next((k for k in keys if k != read), read)}",
                        f"{a} and {b} disagree by {diff:.3g} (largest element); the mounting rotation is read from "
                        f"{at}.{read} and its copies ({', '.join(stored)}) must agree with it within {ROTATION_TOL:g}: edit "
                        "them together, or re-run the calibration")


def _check_free_leg(source: str, at: str, l: dict) -> None:
    kind = l.get("load_kind")
    if kind not in FREE_LOAD_KINDS:
        raise _fail(source, f"{at}.load_kind", f"{kind!r}; expected one of {list(FREE_LOAD_KINDS)}")
    need = ("offset", "load_mass_kg") + (("load_com_m",) if kind == "rigid_payload" else ("urdf", "link", "urdf_groups"))
    if kind == "rigid_payload" and (l.get("link") is not None or l.get("urdf") is not None):
        need += ("urdf", "link")   # a payload oriented by the joints: the correction rebuilds R_nom(q) from the URDF
    missing = [k for k in need if l.get(k) is None]
    if missing:
        raise _fail(source, f"{at}.{missing[0]}", f"missing key(s) {missing} of a {kind} calibration (the contact wrench needs "
                    + ("the offsets, the load's mass and CoM)" if kind == "rigid_payload" else
                       "the offsets, the URDF, the sensor link and the groups' parameters)"))
    _numbers(source, f"{at}.offset", l.get("offset"), (6,))
    for key in ("noise_sd", "residual_rms"):
        if l.get(key) is not None:
            _numbers(source, f"{at}.{key}", l[key], (6,))
    m = l.get("load_mass_kg")
    if not isinstance(m, (int, float)) or isinstance(m, bool) or not np.isfinite(m) or m <= 0:
        raise _fail(source, f"{at}.load_mass_kg", f"{m!r}; expected the load's mass, a positive number (kg)")
    if kind == "rigid_payload":
        _numbers(source, f"{at}.load_com_m", l.get("load_com_m"), (3,))
    else:
        groups = l.get("urdf_groups")
        if not isinstance(groups, dict) or not groups:
            raise _fail(source, f"{at}.urdf_groups", "expected a table of the URDF groups' parameters")
        for name, gr in groups.items():
            if not isinstance(gr, dict):
                raise _fail(source, f"{at}.urdf_groups.{name}", "expected a table with mass_kg and first_moment_kgm")
            _numbers(source, f"{at}.urdf_groups.{name}.mass_kg", gr.get("mass_kg"), ())
            _numbers(source, f"{at}.urdf_groups.{name}.first_moment_kgm", gr.get("first_moment_kgm"), (3,))
    if l.get("gravity_tilt_rad") is not None:
        _numbers(source, f"{at}.gravity_tilt_rad", l["gravity_tilt_rad"], (2,))
    if l.get("gravity_body") is not None:   # the fixed base's gravity direction, for a recording without orientation
        gb = _numbers(source, f"{at}.gravity_body", l["gravity_body"], (3,))
        if abs(float(np.linalg.norm(gb)) - 1.0) > 1e-3:
            raise _fail(source, f"{at}.gravity_body", f"norm {np.linalg.norm(gb):.4g}; expected a unit vector (gravity's "
                                                      "direction in B at calibration)")
    _check_mount(source, at, l)


def _check_hexapod_leg(source: str, at: str, l: dict) -> None:
    _numbers(source, f"{at}.offset", l.get("offset"), (6,))
    _numbers(source, f"{at}.leg_weight_N", l.get("leg_weight_N"), ())
    _rotation(source, f"{at}.rotation_to_body", l.get("rotation_to_body"))
    _numbers(source, f"{at}.position_from_com_m", l.get("position_from_com_m"), (3,))
    grid = l.get("leg_com_grid")
    if not isinstance(grid, dict):
        raise _fail(source, f"{at}.leg_com_grid", "expected a table with phi and xyz")
    try:
        xyz = np.array([[np.nan if v is None else v for v in r] for r in grid.get("xyz") or []], float)
    except (TypeError, ValueError):
        raise _fail(source, f"{at}.leg_com_grid.xyz", "expected rows of three numbers (m)") from None
    if xyz.size == 0 or not np.isfinite(xyz).any():
        raise _fail(source, f"{at}.leg_com_grid.xyz", "holds no finite point; expected the leg's CoM on the grid")


def check_calibration_dict(d: dict, source: str) -> None:
    """A calibration as read from a file, before any command applies it: ``legs`` a non-empty table; ``mass_kg`` and
    ``g`` positive where stored; per hexapod leg the offsets, leg weight, position and CoM grid finite and
    ``rotation_to_body`` a proper rotation; per free load (``load_kind``) the offsets finite, the load mass positive,
    its parameters finite, every stored rotation proper and one mounting rotation (:func:`_check_mount`). Errors
    name the file and the key (``legs.X.key``)."""
    legs = d.get("legs")
    if isinstance(legs, dict) and not legs:
        raise _fail(source, "legs", "an empty table: the calibration holds no transducer; expected the calibrated "
                                    "transducers' entries (a calibration.json written by a run, OUTPUT_FORMAT.md)")
    if not isinstance(legs, dict):
        raise DataFormatError(f"{source}: missing key 'legs' (a table of the calibrated transducers); expected a "
                              "calibration.json written by a run (OUTPUT_FORMAT.md)", path=source, column="legs")
    for key in ("mass_kg", "g"):
        v = d.get(key)
        if v is not None and (not isinstance(v, (int, float)) or isinstance(v, bool) or not np.isfinite(v) or v <= 0):
            raise _fail(source, key, f"{v!r}; expected a positive number")
    g = d.get("g")
    if g is not None and not G_RANGE[0] < g < G_RANGE[1]:
        raise _fail(source, "g", f"{g!r}; expected gravity's magnitude in m/s^2, between {G_RANGE[0]:g} and {G_RANGE[1]:g} "
                                 "(9.81 on Earth), as robot.toml's g")
    for k, l in legs.items():
        if not isinstance(l, dict):
            raise _fail(source, f"legs.{k}", f"expected a table, got {type(l).__name__}")
    free = [k for k, l in legs.items() if "load_kind" in l]
    if free and len(free) < len(legs):
        other = [k for k in legs if k not in free]
        raise _fail(source, f"legs.{other[0]}.load_kind", f"missing, where {free} name theirs; expected one calibration of "
                    "either free loads (every transducer with its load_kind) or hexapod legs")
    for k, l in legs.items():
        (_check_free_leg if "load_kind" in l else _check_hexapod_leg)(source, f"legs.{k}", l)
