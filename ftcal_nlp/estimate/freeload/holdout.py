"""Validation of a free-load calibration on a later session (issue 32 item 6): where it holds, where it does not.

Input, per transducer, from recordings of the free load touching nothing, corrected with the calibration
(``correct.free``): per sample ``n`` the contact wrench ``w_n`` (6,), its se ``s_n`` (6,) (the calibration's
covariance and the readings' noise), the readings' noise sd ``sigma`` (6,) of the calibration, and the direction of
gravity in the transducer's frame ``u_n`` (unit). Touching nothing, ``w_n`` is the calibration's error plus noise, so
per axis ``z_n = w_n / s_n`` is ~N(0, 1) where the calibration holds.

Regions: ``u_n`` goes to the nearest of the 26 directions ``(a, b, c) / |(a, b, c)|``, ``a, b, c`` in ``{-1, 0, 1}``:
the 6 axes of the sensor (``-z``: gravity along the sensor's -z, the tool hanging below it), 12 edges (``+x-z``:
halfway between +x and -z) and 8 corners; every sample lies within 28 deg of its region's centre, the cells of near-equal area (3.5-4.6 % of the sphere). Why this binning: gravity's
direction in the sensor's frame is what a rigid payload's wrench depends on (``w_load = [m g_ft ; c x m g_ft]``),
it is defined alike for a wrist payload (``qw..qz`` or ``gx..gz``), a URDF leg and an arm read through joints, and a
roboticist reads "gravity along +x-z of the sensor" at a glance; the sample nearest each region's centre names a pose
(its time and joint angles or orientation) to go back to. A URDF leg's wrench depends on the joints below the sensor
too: a region then pools every pose of those joints at that gravity direction.

Per region (``n_r`` samples) and axis:

    m = mean_n w_n,     V = (mean_n c_n)^2 + k sigma^2 / n_r,     c_n = sqrt(max(s_n^2 - sigma^2, 0)),
    zbar = m / sqrt(V),   X2 = max over the six axes of zbar^2.

The calibration's part of the se (``c_n``) is one error shared by every sample of the region: the sd of its mean is
at most the mean of the ``c_n`` (equal when its derivative is the same at every sample, Cauchy-Schwarz otherwise: the
test is then conservative). The noise averages down over the region, less so when it stays through a hold: ``k`` the
variance inflation of a mean under AR(1) errors of ``freeload.problem.serial_inflation`` (the estimator's own) on the
region's contact wrench, consecutive samples of one recording; white noise gives ~1, a wrench constant per hold the
samples per run.

Test: a region does not hold where ``X2 > chi2_1^{-1}(1 - alpha / M)``, ``M`` = 6 x the regions with samples, over
every transducer (Bonferroni: valid whatever the correlation between axes and between regions); a good calibration
then fails somewhere with chance at most ``alpha`` (default 1 %). The adjusted p is ``min(1, M P(chi2_1 > X2))``.

Beside it, per axis over all samples and per region: RMS ``z`` (1 where the se are right). Its band for a good
calibration (reported, not part of the verdict), at ``a = alpha / (6 x transducers)`` per axis: over ``n`` samples
``b = sqrt(chi2_nu^{-1}(a/2, 1 - a/2) / nu)``, ``nu = n / k`` (``k`` the inflation over the whole recording), widened
for the calibration's own noise estimate (``noise_sd`` from ``n_cal`` samples: relative sd ``1 / sqrt(2 n_cal)``) in
quadrature on the log scale, ``exp(+-sqrt(log(b)^2 + (z_{a/2} / sqrt(2 n_cal))^2))``. A value above the band says the
se are too small (more noise than at calibration, or an error everywhere), below it too large.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.stats import chi2, norm

from .problem import serial_inflation

AXES = ("fx", "fy", "fz", "tx", "ty", "tz")
ALPHA = 0.01   # the test's size: the chance that a good calibration fails in some region


def _directions() -> tuple[tuple[str, ...], np.ndarray]:
    vecs = [np.array(v, float) for v in itertools.product((1, 0, -1), repeat=3) if any(v)]
    vecs.sort(key=lambda v: (int(np.abs(v).sum()), tuple(-v)))       # axes, then edges, then corners
    names = tuple("".join(f"{'+' if x > 0 else '-'}{a}" for x, a in zip(v, "xyz") if x) for v in vecs)
    return names, np.array([v / np.linalg.norm(v) for v in vecs])


#: the 26 region names ("+x", "+x-z", "+x+y-z") and their unit centres (26, 3), in the sensor's frame
REGION_NAMES, REGION_CENTRES = _directions()


def region_index(u: np.ndarray) -> np.ndarray:
    """Index into :data:`REGION_NAMES` of each direction ``u`` (N, 3): the nearest centre (largest dot product)."""
    return np.argmax(np.asarray(u, float) @ REGION_CENTRES.T, axis=1)


@dataclass(frozen=True)
class LegSamples:
    """One transducer's samples of the later session: contact wrench ``w`` (N, 6) and se ``se`` (N, 6), the calibration's
    noise sd ``sigma`` (6,), gravity in the sensor's frame ``u`` (N, 3, unit), ``source`` (N,) the recording of each
    sample (int) and ``index`` (N,) its row there, ``t`` (N,) its time, ``poses`` the pose columns (joint angles,
    orientation) of each sample (N rows) or None, ``n_cal`` the calibration's samples (``samples_used``)."""

    leg: str
    w: np.ndarray
    se: np.ndarray
    sigma: np.ndarray
    u: np.ndarray
    source: np.ndarray
    index: np.ndarray
    t: np.ndarray
    poses: pd.DataFrame | None = None
    n_cal: int | None = None     # the samples the calibration's noise sd rests on (None: not known, taken exact)

    def __post_init__(self) -> None:
        n = len(self.w)
        shapes = {"w": (n, 6), "se": (n, 6), "sigma": (6,), "u": (n, 3), "source": (n,), "index": (n,), "t": (n,)}
        bad = [k for k, s in shapes.items() if np.shape(getattr(self, k)) != s]
        if bad:
            raise ValueError(f"LegSamples {self.leg}: shapes of {bad} are not {[shapes[k] for k in bad]}")
        if self.poses is not None and len(self.poses) != n:
            raise ValueError(f"LegSamples {self.leg}: poses has {len(self.poses)} rows for {n} samples")

    @property
    def z(self) -> np.ndarray:
        """Per sample and axis ``w / se`` (N, 6); NaN where the se is not finite (an undetermined direction)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(np.isfinite(self.se) & (self.se > 0), self.w / self.se, np.nan)


@dataclass(frozen=True)
class Region:
    """One region of one transducer (module docstring): ``name`` of :data:`REGION_NAMES`, ``centre`` (3,), ``n``
    samples in ``runs`` runs of consecutive samples, RMS force and torque error (N, N*m) and RMS se, RMS ``z`` per
    axis, the mean error ``mean`` (6,) with its se ``mean_se`` (6,), ``zbar`` (6,), ``inflation`` (6,), ``stat``
    (``X2``), ``p`` (Bonferroni-adjusted), ``holds``, and ``pose`` (time and pose columns of the sample nearest the
    centre)."""

    leg: str
    name: str
    centre: np.ndarray
    n: int
    runs: int
    rms_force: float
    rms_torque: float
    rms_force_se: float
    rms_torque_se: float
    rms_z: np.ndarray
    mean: np.ndarray
    mean_se: np.ndarray
    zbar: np.ndarray
    inflation: np.ndarray
    stat: float
    p: float
    holds: bool
    pose: dict = field(default_factory=dict)

    @property
    def tested(self) -> bool:
        """Whether some axis has a finite se of its mean (none: the calibration gives no se, nothing to test)."""
        return bool(np.isfinite(self.stat))

    @property
    def worst_axis(self) -> str:
        return AXES[int(np.nanargmax(np.abs(self.zbar)))] if self.tested else AXES[0]


@dataclass(frozen=True)
class LegHoldout:
    """One transducer's validation: ``n`` samples, RMS ``z`` per axis over them with its expected ``band`` (lo, hi)
    and the inflation ``k`` (6,) it rests on, and its regions (non-empty, in the order of :data:`REGION_NAMES`)."""

    leg: str
    n: int
    rms_z: np.ndarray
    band: tuple[float, float]
    inflation: np.ndarray
    regions: tuple[Region, ...]

    @property
    def failing(self) -> tuple[Region, ...]:
        return tuple(r for r in self.regions if not r.holds)


@dataclass(frozen=True)
class Holdout:
    """The validation of every transducer at size ``alpha``: ``tests`` (``M``) and the chi^2 (1 dof) ``threshold``."""

    legs: dict[str, LegHoldout]
    alpha: float
    tests: int
    threshold: float

    @property
    def failing(self) -> tuple[Region, ...]:
        return tuple(r for h in self.legs.values() for r in h.failing)

    @property
    def holds(self) -> bool:
        return not self.failing


def _region_moments(s: LegSamples, sel: np.ndarray) -> dict:
    """The statistics of the samples ``sel`` of ``s`` that do not depend on the test's size (module docstring)."""
    w, se, z = s.w[sel], s.se[sel], s.z[sel]
    n = len(w)
    order = np.lexsort((s.index[sel], s.source[sel]))
    w_o, src, idx = w[order], s.source[sel][order], s.index[sel][order]
    _, k = serial_inflation(w_o, src, idx)
    runs = int(np.sum((np.diff(idx) != 1) | (np.diff(src) != 0))) + 1 if n else 0
    cal = np.sqrt(np.clip(se**2 - s.sigma**2, 0.0, None))
    mean_se = np.sqrt(cal.mean(0) ** 2 + k * s.sigma**2 / n)
    mean = w.mean(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        zbar = np.where(np.isfinite(mean_se) & (mean_se > 0), mean / mean_se, np.nan)
    return {"n": n, "runs": runs, "rms_force": float(np.sqrt((w[:, :3] ** 2).sum(1).mean())),
            "rms_torque": float(np.sqrt((w[:, 3:] ** 2).sum(1).mean())),
            "rms_force_se": float(np.sqrt((se[:, :3] ** 2).sum(1).mean())),
            "rms_torque_se": float(np.sqrt((se[:, 3:] ** 2).sum(1).mean())),
            "rms_z": np.sqrt(np.nanmean(z**2, axis=0)), "mean": mean, "mean_se": mean_se, "zbar": zbar, "inflation": k,
            "stat": float(np.nanmax(zbar**2)) if np.isfinite(zbar).any() else np.nan}


def _nearest_pose(s: LegSamples, sel: np.ndarray, centre: np.ndarray) -> dict:
    i = np.flatnonzero(sel)[int(np.argmax(s.u[sel] @ centre))]
    pose = {"t": float(s.t[i]), "source": int(s.source[i])}
    if s.poses is not None:
        pose.update({str(c): float(v) for c, v in s.poses.iloc[i].items()})
    return pose


def rms_band(n_eff: float, alpha: float = ALPHA, n_cal: float | None = None) -> tuple[float, float]:
    """The two-sided ``1 - alpha`` band of RMS z over ``n_eff`` independent N(0, 1) samples, widened for a noise sd
    estimated from ``n_cal`` samples (module docstring; None: known exactly)."""
    nu = max(float(n_eff), 1.0)
    lo, hi = np.log(np.sqrt(chi2.ppf(alpha / 2, nu) / nu)), np.log(np.sqrt(chi2.isf(alpha / 2, nu) / nu))
    if n_cal:
        c = (float(norm.isf(alpha / 2)) / np.sqrt(2.0 * n_cal)) ** 2
        lo, hi = -np.sqrt(lo**2 + c), np.sqrt(hi**2 + c)
    return float(np.exp(lo)), float(np.exp(hi))


def holdout(samples: dict[str, LegSamples], alpha: float = ALPHA, min_samples: int = 2) -> Holdout:
    """The validation of each transducer's samples (module docstring); regions with fewer than ``min_samples``
    samples are left out (and out of the count of tests)."""
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    moments: dict[str, list[tuple[int, dict]]] = {}
    for leg, s in samples.items():
        r = region_index(s.u)
        moments[leg] = [(j, _region_moments(s, r == j)) for j in range(len(REGION_NAMES)) if (r == j).sum() >= min_samples]
    tests = 6 * sum(len(v) for v in moments.values())
    thr = float(chi2.isf(alpha / max(tests, 1), 1))
    legs = {}
    for leg, s in samples.items():
        r = region_index(s.u)
        regions = []
        for j, m in moments[leg]:
            p = float(min(1.0, tests * chi2.sf(m["stat"], 1))) if np.isfinite(m["stat"]) else np.nan
            regions.append(Region(leg, REGION_NAMES[j], REGION_CENTRES[j], holds=not (m["stat"] > thr), p=p,
                                  pose=_nearest_pose(s, r == j, REGION_CENTRES[j]), **m))
        order = np.lexsort((s.index, s.source))
        _, k = serial_inflation(s.w[order], s.source[order], s.index[order])
        legs[leg] = LegHoldout(leg, len(s.w), np.sqrt(np.nanmean(s.z**2, axis=0)),
                               rms_band(len(s.w) / float(np.max(k)), alpha / (6 * len(samples)), s.n_cal), k,
                               tuple(regions))
    return Holdout(legs, alpha, tests, thr)


def holdout_table(h: Holdout) -> pd.DataFrame:
    """One row per transducer and region: what :class:`Region` holds, flat (the pose's columns prefixed ``pose_``)."""
    rows = []
    for lh in h.legs.values():
        for r in lh.regions:
            row = {"transducer": r.leg, "region": r.name, "holds": int(r.holds), "n": r.n, "runs": r.runs,
                   **{f"centre_{c}": float(v) for c, v in zip("xyz", r.centre)},
                   "rms_force_N": r.rms_force, "rms_force_se_N": r.rms_force_se,
                   "rms_torque_Nm": r.rms_torque, "rms_torque_se_Nm": r.rms_torque_se,
                   **{f"rms_z_{a}": float(v) for a, v in zip(AXES, r.rms_z)},
                   **{f"mean_{a}": float(v) for a, v in zip(AXES, r.mean)},
                   **{f"mean_se_{a}": float(v) for a, v in zip(AXES, r.mean_se)},
                   **{f"zbar_{a}": float(v) for a, v in zip(AXES, r.zbar)},
                   "chi2_max": r.stat, "chi2_threshold": h.threshold, "p_bonferroni": r.p,
                   **{f"pose_{k}": v for k, v in r.pose.items()}}
            rows.append(row)
    return pd.DataFrame(rows)


def _fmt_pose(pose: dict, sources: list[str] | None) -> str:
    src = pose.get("source")
    where = f"{sources[src]} " if sources and src is not None and src < len(sources) else ""
    rest = ", ".join(f"{k.removeprefix('q_')} {v:.3g}" for k, v in pose.items() if k not in ("t", "source"))
    return f"{where}t = {pose['t']:.15g}" + (f" ({rest})" if rest else "")


def holdout_markdown(h: Holdout, sources: list[str] | None = None, calibration: str = "the calibration") -> str:
    """``holdout.md``: the verdict, then per transducer its RMS z and a line per region (failing ones first, named)."""
    test = (f"a region does not hold where its mean contact wrench exceeds its se on some axis: max zbar^2 > "
            f"{h.threshold:.3g} (chi^2, 1 dof, at {h.alpha:g} / {h.tests}: Bonferroni over 6 axes x the regions)")
    lines = ["# Validation on a later session", "",
             f"Calibration: {calibration}. Recordings: {', '.join(sources) if sources else '-'}.", "",
             "Regions: the direction of gravity in the transducer's frame, to the nearest of 26 directions (6 axes, 12 "
             "edges, 8 corners); serial correlation within holds accounted for (freeload/holdout.py). Test: " + test + ".", ""]
    regions = [r for l in h.legs.values() for r in l.regions]
    untested = sum(not r.tested for r in regions)
    if h.holds and untested == len(regions):
        lines += ["**Nothing tested**: the calibration gives no se (no covariance file, no noise sd stored).", ""]
    elif h.holds:
        lines += [f"**The calibration holds in every region** ({len(regions)} regions"
                  + (f"; {untested} without se, untested" if untested else "") + ").", ""]
    else:
        names = "; ".join(f"{r.leg} gravity along {r.name} ({r.worst_axis} off by {r.mean[AXES.index(r.worst_axis)]:.3g} "
                          f"+- {r.mean_se[AXES.index(r.worst_axis)]:.2g})" for r in h.failing)
        lines += [f"**The calibration does not hold at: {names}.**", ""]
        n_all = sum(len(l.regions) for l in h.legs.values())
        if len(h.failing) > n_all / 2:
            lines += [f"It fails in {len(h.failing)} of {n_all} regions: the load touched something throughout, or changed "
                      "(another tool, a cable re-routed), or the calibration is of another sensor or mounting.", ""]
    for lh in h.legs.values():
        out = [a for a, v in zip(AXES, lh.rms_z) if not lh.band[0] <= v <= lh.band[1]]
        lines += [f"## {lh.leg}", "",
                  f"{lh.n} samples; RMS z per axis " + ", ".join(f"{a} {v:.3f}" for a, v in zip(AXES, lh.rms_z))
                  + f" (expected {lh.band[0]:.3f}-{lh.band[1]:.3f} at {h.alpha:g} over the six axes"
                  + (f"; outside: {out}: the se do not fit the scatter there" if out else "") + ").", "",
                  "| region | verdict | n | RMS force N (se) | RMS torque N*m (se) | worst axis: mean +- se | p | pose nearest the centre |",
                  "|---|---|---|---|---|---|---|---|"]
        for r in sorted(lh.regions, key=lambda r: r.holds):
            a = AXES.index(r.worst_axis)
            verdict = "holds" if r.holds and r.tested else "untested (no se)" if r.holds else "**does not hold**"
            lines.append(f"| {r.name} | {verdict} | {r.n} | {r.rms_force:.3g} "
                         f"({r.rms_force_se:.2g}) | {r.rms_torque:.3g} ({r.rms_torque_se:.2g}) | {r.worst_axis}: "
                         f"{r.mean[a]:.3g} +- {r.mean_se[a]:.2g} | {r.p:.2g} | {_fmt_pose(r.pose, sources)} |")
        lines.append("")
    return "\n".join(lines)


def plot_holdout(h: Holdout, samples: dict[str, LegSamples], path, max_points: int = 6000) -> None:
    """``holdout.png``: per transducer the mean force and torque error per region with the test's limit
    (``+- sqrt(threshold) x se``; failing regions in red) and a Mollweide map of gravity's direction in the sensor's
    frame (longitude atan2(u_y, u_x), latitude asin(u_z)), each sample coloured by its region's ``sqrt(X2)`` (the
    test's limit marked on the colour bar)."""
    import matplotlib.pyplot as plt   # the backend is the entry point's choice (cli.setup)

    legs = list(h.legs)
    fig = plt.figure(figsize=(18, 4.6 * len(legs)))
    lim = np.sqrt(h.threshold)
    for i, leg in enumerate(legs):
        lh, s = h.legs[leg], samples[leg]
        x = np.arange(len(lh.regions))
        for col, (sl, unit) in enumerate(((slice(0, 3), "N"), (slice(3, 6), "N*m"))):
            ax = fig.add_subplot(len(legs), 3, 3 * i + col + 1)
            for j, a in enumerate(AXES[sl]):
                m = np.array([r.mean[sl][j] for r in lh.regions])
                e = np.array([r.mean_se[sl][j] for r in lh.regions])
                ax.errorbar(x + (j - 1) * 0.2, m, yerr=lim * e, fmt="o", ms=3, capsize=2, label=f"{a} (+- {lim:.2f} se)")
            ax.axhline(0, color="k", lw=0.5)
            ax.set_xticks(x, [r.name for r in lh.regions], rotation=90, fontsize=7)
            for t, r in zip(ax.get_xticklabels(), lh.regions):
                if not r.holds:
                    t.set_color("red")
                    t.set_fontweight("bold")
            for j, r in enumerate(lh.regions):
                if not r.holds:
                    ax.axvspan(j - 0.45, j + 0.45, color="red", alpha=0.12)
            ax.set_ylabel(f"{leg}: mean contact {'force' if col == 0 else 'torque'} ({unit})")
            ax.set_xlabel("gravity's direction in the sensor frame (region)")
            ax.legend(fontsize=7)
        ax = fig.add_subplot(len(legs), 3, 3 * i + 3, projection="mollweide")
        step = max(1, len(s.u) // max_points)
        u = s.u[::step]
        # each sample coloured by its region's largest |mean / se|: where the test looks, on the sphere
        zr = np.full(len(REGION_NAMES), np.nan)
        zr[[REGION_NAMES.index(r.name) for r in lh.regions]] = [np.sqrt(r.stat) for r in lh.regions]
        sc = ax.scatter(np.arctan2(u[:, 1], u[:, 0]), np.arcsin(np.clip(u[:, 2], -1, 1)), c=zr[region_index(u)], s=3,
                        cmap="viridis", vmin=0, vmax=2 * lim)
        cb = fig.colorbar(sc, ax=ax, shrink=0.7, label="region's max |mean error / se|")
        cb.ax.axhline(lim, color="red", lw=2)
        for r in lh.regions:
            c = r.centre
            ax.annotate(r.name, (np.arctan2(c[1], c[0]), np.arcsin(c[2])), fontsize=7, ha="center",
                        color="red" if not r.holds else "black", fontweight="bold" if not r.holds else "normal")
        ax.set_title(f"{leg}: gravity's direction in the sensor frame\n(longitude from +x toward +y, latitude toward +z)",
                     fontsize=9)
        ax.set_xticklabels([])
        ax.grid(True, alpha=0.3)
    fig.suptitle("holds everywhere" if h.holds else
                 "does not hold at: " + ", ".join(f"{r.leg} {r.name}" for r in h.failing), color="k" if h.holds else "red")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
