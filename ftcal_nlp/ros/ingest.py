"""ROS bags -> interchange dataset (``DATA_FORMAT.md``), on one clock.

For each ``[[recording]]`` of a map (:mod:`.mapfile`) the bag's streams
(:mod:`.bagio`) are resampled (:mod:`.clock`) onto the *wrench clock*: the
header stamps of the first leg's ``WrenchStamped`` topic. Per clock row

* the other legs' readings are the nearest sample within half a wrench period
  (``wrench_match = "linear"``: the chord between the bracketing samples, where
  one lies within half a period); a row where one is missing is dropped and
  counted per leg;
* ``{leg}_phi = sign * (unwrap(position) - zero_rad)``, linear in time; rows
  outside the joint stream's span or inside a joint gap longer than
  ``[joints] max_gap_s`` are dropped and counted;
* ``qw..qz`` (standing and walking only) is the slerp of the mocap orientation (``R_WB``; with
  ``[body_pose] link`` the tracked link's ``R_WM R_BM^T``); outside the mocap
  span or inside a gap longer than ``[body_pose] max_gap_s`` it is NaN
  (tracking lost, as the format says), never bridged or extrapolated;
* ``t`` is seconds since the session epoch, the earliest stamp of any stream
  used in any bag of the map, so later recordings have larger ``t``.

Before resampling, every stream the map names must exist with at least two
samples, non-zero header stamps that never step back (in bag order) by more
than ``max_backward_s``, and (``check_frame_ids``) WrenchStamped frames equal to
the transducer links; errors name the bag, topic, map key and what was
expected. :func:`write_ingested` writes over nothing unless asked.

Readings are multiplied by ``wrench_sign`` and otherwise passed through: the
format's reading is the wrench the leg exerts on the transducer, in ``ft_k``
about its origin, offset included (report eq. 1).

Section 5 (:mod:`.freeload`): ``[joint_columns]`` adds ``q_{joint}`` columns and ``[imu]`` ``qw..qz`` or
``gx..gz`` on the same clock (rows without a joint position or an accelerometer gravity dropped and
counted); legs without a ``[joints]`` entry get no ``{leg}_phi``; hanging recordings without
``gravity_body`` read the orientation per sample and need no opposite partner.
"""

from __future__ import annotations

import logging
import shutil
from functools import partial
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from ..core.data import (
    QUAT_COLUMNS,
    WRENCH_COMPONENTS,
    DataFormatError,
    Dataset,
    Recording,
    hanging_pairs,
    recording_from_frame,
    recording_to_frame,
    write_robot,
)
from ..core.csvout import write_csv
from ..core.errors import ConfigError, OutputExistsError
from .bagio import BagError, BagStreams, Stream, read_streams
from .counts import IngestCounts, IngestResult, check_not_backwards, seconds, summary
from .clock import interp_linear, match_nearest, median_period, slerp_quat, sort_unique
from .arm import ArmMap, ingest_arm, read_arm_map
from .mapfile import IngestMap, RecordingSpec, load_map, read_map

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------- checks


def _check_topics(m: IngestMap, spec: RecordingSpec, topics: dict[str, str]) -> None:
    """Every topic the map names is in the bag; errors name the map key."""
    listing = ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items()))
    for k, t in m.wrench_topics.items():
        if t not in topics:
            raise BagError(f"{spec.bag}: topic '{t}' of map key [wrench_topics] {k} is not in the bag (topics: {listing})")
    if m.joint_topic is not None and m.joint_topic not in topics:
        raise BagError(f"{spec.bag}: topic '{m.joint_topic}' of map key [joints] topic is not in the bag (topics: {listing})")
    if m.free_keys is not None and m.free_keys.imu is not None and m.free_keys.imu.topic not in topics:
        raise BagError(f"{spec.bag}: topic '{m.free_keys.imu.topic}' of map key [imu] topic is not in the bag (topics: {listing})")
    if spec.kind != "hanging" and m.pose_topic not in topics:
        raise BagError(f"{spec.bag}: topic '{m.pose_topic}' of map key [body_pose] topic is not in the bag (topics: {listing}); "
                       f"a {spec.kind} recording needs the body orientation")


def _check_streams(m: IngestMap, spec: RecordingSpec, s: BagStreams) -> None:
    for k, t in m.wrench_topics.items():
        if len(s.wrench[t]) < 2:
            raise BagError(f"{spec.bag}: topic '{t}' ([wrench_topics] {k}) has {len(s.wrench[t])} message(s); at least 2 are needed")
        if m.check_frame_ids and m.transducer_links is not None:
            link = m.transducer_links[k]
            other = sorted(f for f in s.wrench[t].frame_ids if f and f != link)
            if other:
                raise BagError(
                    f"{spec.bag}: topic '{t}' ([wrench_topics] {k}) is stamped in frame(s) {other}, but [transducer_links] {k} = '{link}'; "
                    "readings must be in the transducer frame (fix the map or the driver, or set check_frame_ids = false if the frames are the same)"
                )
    for k, n in m.joint_names.items():
        if n not in s.joints:
            seen = sorted(s.joint_names_seen)
            raise BagError(f"{spec.bag}: joint '{n}' of map key [joints] {k} never has a position on '{m.joint_topic}' (joint names seen: {seen})")
        if len(s.joints[n]) < 2:
            raise BagError(f"{spec.bag}: joint '{n}' ([joints] {k}) has fewer than 2 positions")
    jc = m.free_keys.joint_columns if m.free_keys is not None else None
    for n in jc.names if jc is not None else ():
        if n not in s.joints or len(s.joints[n]) < 2:
            raise BagError(f"{spec.bag}: joint '{n}' of map key [joint_columns] names has fewer than 2 positions on "
                           f"'{jc.topic if jc is not None else None}' (joint names seen: {sorted(s.joint_names_seen)})")
    imu = s.extra.get("imu")
    if imu is not None and len(imu) < 2:
        raise BagError(f"{spec.bag}: topic '{imu.topic}' ([imu] topic) has {len(imu)} message(s); at least 2 are needed")
    if spec.kind != "hanging" and (s.pose is None or len(s.pose) < 2):
        raise BagError(f"{spec.bag}: topic '{m.pose_topic}' ([body_pose] topic) has fewer than 2 valid orientations")
    if m.time_source == "header":
        named = [(f"[wrench_topics] {k}", s.wrench[t]) for k, t in m.wrench_topics.items()]
        named += [(f"[joints] {k}", s.joints[n]) for k, n in m.joint_names.items()]
        named += [("[body_pose] topic", s.pose)] if s.pose is not None else []
        for key, st in named:
            if np.any(st.stamp_ns <= 0):
                raise BagError(f"{spec.bag}: topic '{st.topic}' ({key}) has messages with zero header stamps; "
                               "the publisher does not stamp them: set time_source = \"receive\" in the map to use bag receive times")
            check_not_backwards(spec, key, st, m.max_backward_s)


def _stamps(st: Stream, m: IngestMap) -> np.ndarray:
    return st.stamp_ns if m.time_source == "header" else st.receive_ns


def _streams_used(m: IngestMap, s: BagStreams) -> list[Stream]:
    out = [s.wrench[t] for t in m.wrench_topics.values()] + [s.joints[n] for n in m.joint_names.values()]
    jc = m.free_keys.joint_columns if m.free_keys is not None else None
    out += [s.joints[n] for n in (jc.names if jc is not None else ()) if n in s.joints]
    out += [s.extra["imu"]] if s.extra.get("imu") is not None else []
    return out + ([s.pose] if s.pose is not None else [])


# ----------------------------------------------------------------------------- resampling


def resample(m: IngestMap, spec: RecordingSpec, s: BagStreams, epoch_ns: int) -> tuple[pd.DataFrame, IngestCounts]:
    """One bag's streams on its wrench clock, as a table with the format's columns.

    Rows where a reading or a shaft angle is missing are left out; missing
    orientation is NaN. Returns the table and what was dropped.
    """
    legs = m.legs
    first = s.wrench[m.wrench_topics[legs[0]]]
    clock_ns, w0, n_dup = sort_unique(_stamps(first, m), first.values)
    t = seconds(clock_ns, epoch_ns)
    period = median_period(t)
    dt = np.diff(t)
    clock_gaps = int(np.sum(np.round(dt[dt > 1.5 * period] / period) - 1))
    keep = np.ones(len(t), dtype=bool)
    wrench = {legs[0]: w0}
    unmatched = {}
    for k in legs[1:]:
        st = s.wrench[m.wrench_topics[k]]
        sk, vk, _ = sort_unique(seconds(_stamps(st, m), epoch_ns), st.values)
        # A row has a reading of leg k when one of its samples lies within half a
        # period; "linear" then takes the chord between the bracketing samples.
        idx = match_nearest(t, sk, 0.5 * period)
        miss = idx < 0
        if m.wrench_match == "nearest":
            wrench[k] = np.where(miss[:, None], np.nan, vk[np.maximum(idx, 0)])
        else:
            r = interp_linear(t, sk, vk)
            miss |= r.missing
            wrench[k] = r.values
        unmatched[k] = int(miss.sum())
        keep &= ~miss
    outside, gap = {}, {}
    phi = {}
    for k in m.joint_names:
        st = s.joints[m.joint_names[k]]
        sj, pj, _ = sort_unique(seconds(_stamps(st, m), epoch_ns), st.values[:, 0])
        # Unwrap in the stream's own order, before resampling: a wrapped angle
        # interpolated across the +-pi seam would sweep the whole circle.
        pos = m.joint_sign[k] * (np.unwrap(pj) - m.joint_zero_rad[k])
        r = interp_linear(t, sj, pos, m.joint_max_gap_s)
        phi[k] = r.values[:, 0]
        outside[k], gap[k] = int(r.outside.sum()), int(r.in_gap.sum())
        keep &= ~r.missing
    free = None
    if m.free_keys is not None:                 # section 5: q_{joint}, IMU (ros/freeload.py)
        from .freeload import free_columns

        free = free_columns(m.free_keys, s.joints, s.extra.get("imu"), t, lambda x: seconds(x, epoch_ns), lambda st: _stamps(st, m))
        keep &= free.keep
    # NaN or infinite values inside a bag's messages (a driver's fault flag) drop the row too.
    readings = np.concatenate([np.stack([phi[k] for k in phi], 1) if phi else np.zeros((len(t), 0))] + [wrench[k] for k in legs], axis=1)
    bad = keep & ~np.all(np.isfinite(readings), axis=1)
    keep &= ~bad
    quat = None
    n_invalid_pose = 0
    if s.pose is not None and len(s.pose) >= 1:
        n_invalid_pose = s.pose.n_invalid
        sp, qp, _ = sort_unique(seconds(_stamps(s.pose, m), epoch_ns), s.pose.values)
        if m.R_marker_to_body is not None:
            qp = _right_multiply(qp, m.R_marker_to_body)
        quat = slerp_quat(t, sp, qp, m.pose_max_gap_s).values[keep]
    cols: dict[str, np.ndarray] = {"t": t[keep]}
    for k in legs:
        if k in phi:
            cols[f"{k}_phi"] = phi[k][keep]
        w = m.wrench_sign[k] * wrench[k][keep]
        for j, c in enumerate(WRENCH_COMPONENTS):
            cols[f"{k}_{c}"] = w[:, j]
    if quat is not None:
        for j, c in enumerate(QUAT_COLUMNS):
            cols[c] = quat[:, j]
    if free is not None:
        cols.update({c: v[keep] for c, v in free.columns.items()})
    df = pd.DataFrame(cols)
    counts = IngestCounts(
        name=spec.name,
        bag=str(spec.bag),
        n_clock=len(t),
        n_rows=int(keep.sum()),
        duplicate_stamps=n_dup,
        clock_gaps=clock_gaps,
        unmatched_wrench=unmatched,
        joint_outside_span=outside,
        joint_gap=gap,
        nan_readings=int(bad.sum()),
        nan_orientation=0 if quat is None else int(np.isnan(quat[:, 0]).sum()),
        invalid_pose_samples=n_invalid_pose,
        joint_columns_dropped={} if free is None else free.joint_dropped,
        imu_dropped=0 if free is None else free.imu_dropped,
    )
    return df, counts


def _right_multiply(q_wxyz: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Quaternions of ``R(q) R`` (constant right factor commutes with slerp)."""
    from scipy.spatial.transform import Rotation

    r = Rotation.from_quat(q_wxyz[:, [1, 2, 3, 0]]) * Rotation.from_matrix(R)
    return r.as_quat()[:, [3, 0, 1, 2]]


# ----------------------------------------------------------------------------- driver


def read_bags(m: IngestMap, *, progress: bool | None = None) -> list[BagStreams]:
    """Read every bag of the map once, checking topics, joints, frames and stamps against the map.

    ``progress``: a progress bar over each bag's messages (None: when stderr is a terminal).
    """
    out = []
    for spec in m.recordings:
        s = read_streams(
            spec.bag,
            wrench_topics=m.wrench_topics.values(),
            joint_topic=m.joint_topic,
            joint_names=list(m.joint_names.values()) + list(m.free_keys.joint_columns.names if m.free_keys and m.free_keys.joint_columns else ()),
            # hanging recordings do without orientation unless it gives their gravity per sample (section 5)
            pose_topic=m.pose_topic if spec.kind != "hanging" or spec.gravity_body is None else None,
            check_topics=partial(_check_topics, m, spec),
            progress=progress,
        )
        if m.free_keys is not None and m.free_keys.imu is not None:
            from dataclasses import replace as _replace

            from .freeload import read_imu

            s = _replace(s, extra={**s.extra, "imu": read_imu(spec.bag, m.free_keys.imu.topic)})
        _check_streams(m, spec, s)
        out.append(s)
    return out


def session_epoch_ns(m: IngestMap, streams: list[BagStreams]) -> int:
    """The earliest stamp of any stream the map uses, over all its bags (ns)."""
    return int(min(int(_stamps(st, m).min()) for s in streams for st in _streams_used(m, s) if len(st)))


def read_any_map(path: str | Path) -> IngestMap | ArmMap:
    """An ``[arm]`` map (:mod:`.arm`) or any other (:mod:`.mapfile`), read and validated."""
    path = Path(path)
    d = load_map(path)
    return read_arm_map(d, path) if "arm" in d else read_map(path)


def ingest(map_or_path: IngestMap | ArmMap | str | Path, *, progress: bool | None = None) -> IngestResult:
    """Read a map and its bags into a validated :class:`Dataset` (nothing written).

    ``progress``: a progress bar over each bag's messages (None: when stderr is a terminal).
    """
    m = map_or_path if isinstance(map_or_path, (IngestMap, ArmMap)) else read_any_map(map_or_path)
    if isinstance(m, ArmMap):                     # an arm: JointState + WrenchStamped (+ Temperature) + URDF
        return ingest_arm(m, progress=progress)
    streams = read_bags(m, progress=progress)
    epoch = session_epoch_ns(m, streams)
    recs: list[Recording] = []
    counts = []
    for spec, s in zip(m.recordings, streams):
        df, c = resample(m, spec, s, epoch)
        if len(df) < 2:
            raise DataFormatError(f"{spec.bag}: only {len(df)} row(s) left on the wrench clock after alignment ({summary(c)})")
        # The format's own validation (units, monotonic t, NaN readings, unit quaternions).
        rec = recording_from_frame(df, m.robot, name=spec.name, kind=spec.kind, gravity_body=spec.gravity_body, source=str(spec.bag),
                                   payload_legs=m.payload_legs)
        if spec.kind != "hanging" and c.nan_orientation == c.n_rows:
            log.warning("%s: no row has a body orientation (mocap never overlaps the wrench clock)", spec.bag)
        log.info("%s -> %s: %s", spec.bag, spec.name, summary(c))
        recs.append(rec)
        counts.append(c)
    ds = Dataset(m.robot, tuple(recs), None)
    if not m.payload_legs and all(r.gravity_body is not None for r in ds.hanging):   # hexapod legs: opposite pairs
        hanging_pairs(ds.hanging)
    return IngestResult(ds, tuple(counts), epoch, m)


def write_ingested(result: IngestResult, folder: str | Path, *, fmt: str | None = None, overwrite: bool = False) -> Path:
    """Write the dataset (``dataset.toml``, ``robot.toml``, one file per bag); returns the manifest.

    Refuses (``FileExistsError``, nothing written) when any of these files
    exists, unless ``overwrite``; the manifest is written last.

    The manifest also holds, under keys the reader ignores, the bag of each
    recording, its counts and the session epoch (``[ingest] epoch_ns``). A robot
    with a URDF (section 5) gets it copied beside ``robot.toml``, which names it.
    """
    import tomli_w

    fmt = fmt or result.map.fmt
    if fmt not in ("csv", "parquet"):
        raise ConfigError(f"fmt must be 'csv' or 'parquet', got {fmt!r}", key="fmt")
    folder = Path(folder)
    manifest = folder / "dataset.toml"
    ds = result.dataset
    # Every file this would write is checked first: nothing is written over unless asked,
    # not even the recordings of a dataset whose manifest is gone.
    targets = [manifest, folder / "robot.toml"] + [folder / f"{rec.name}.{fmt}" for rec in ds.recordings]
    urdf = ds.robot.urdf
    if urdf is not None and not ((folder / urdf.name).exists() and (folder / urdf.name).samefile(urdf)):
        targets.append(folder / urdf.name)
    inside = folder.resolve()
    for t in targets:  # the map's names are checked when read; a result built by hand is checked here
        if t.resolve().parent != inside:
            raise DataFormatError(f"{t}: would be written outside {folder}; a recording name must be a plain file stem")
    present = [str(x) for x in targets if x.exists()]
    if present and not overwrite:
        raise OutputExistsError(f"{folder}: would write over {present}; pass overwrite=True (--overwrite) to replace them", path=folder)
    if folder.exists() and not folder.is_dir():
        raise OutputExistsError(f"{folder} exists and is not a folder", path=folder)
    folder.mkdir(parents=True, exist_ok=True)
    write_robot(ds.robot, folder / "robot.toml")
    if urdf is not None and folder / urdf.name in targets:
        shutil.copyfile(urdf, folder / urdf.name)
    entries = []
    for rec, c in zip(ds.recordings, result.counts):
        fname = f"{rec.name}.{fmt}"
        df = recording_to_frame(rec, ds.robot.legs)   # section-5 columns too
        if fmt == "parquet":
            df.to_parquet(folder / fname, index=False)
        else:
            write_csv(df, folder / fname)  # every float to the last bit (csvout.py), whatever the epoch
        e: dict = {"file": fname, "kind": rec.kind}
        if rec.gravity_body is not None:
            e["gravity_body"] = [float(x) for x in rec.gravity_body]
        e["bag"] = str(Path(c.bag).resolve())
        e["ingest_counts"] = {k: v for k, v in asdict(c).items() if k not in ("name", "bag")}
        entries.append(e)
    meta = {"map": str(result.map.path.resolve()), "epoch_ns": int(result.epoch_ns), "time_source": result.map.time_source}
    manifest.write_bytes(tomli_w.dumps({"robot": "robot.toml", "recording": entries, "ingest": meta}).encode())
    return manifest
