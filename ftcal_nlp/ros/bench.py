"""Ingest benchmark: a standing bag of the simulator (~1 million messages for 300 poses), timed.

``python -m ftcal_nlp.ros.bench [N_POSES] [STORAGE ...]`` prints one line per
storage. Not a test (it takes tens of seconds); the numbers go in reports.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ..core.data import Dataset
from .bagio import read_streams
from .ingest import ingest, read_bags
from .mapfile import read_map
from .simbag import write_session


def bench_ingest(n_poses: int = 300, *, storage: str = "mcap", seed: int = 0, folder: str | Path | None = None,
                 progress: bool | None = False, fast: bool = True) -> dict:
    """Time the ingest of one simulated standing recording of ``n_poses`` poses.

    Returns ``storage``, ``n_poses``, ``n_messages`` (in the bag), ``n_rows``
    (source rows), ``rows_out`` (ingested rows), ``write_s`` (bag writing),
    ``read_s`` (reading and decoding the bag: :func:`read_bags`), ``ingest_s``
    (the whole :func:`ingest`, reading included), ``messages_per_s`` (of the
    ingest) and ``max_wrench_error`` (N or N*m, ingested vs source rows: 0 when
    the decoder is right). ``fast=False`` times the per-message deserialiser
    for comparison (reading only; ``ingest_s`` is then NaN).
    """
    from ..sim import SimConfig, simulate

    res = simulate(SimConfig(seed=seed, n_poses=n_poses, hanging_cycles=0.25, walk_cycles=0))
    stand = next(r for r in res.dataset.recordings if r.kind == "standing")
    ds = Dataset(res.dataset.robot, (stand,), None)
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        t0 = time.perf_counter()
        mp = write_session(ds, tmp, storage)
        write_s = time.perf_counter() - t0
        m = read_map(mp)
        t0 = time.perf_counter()
        if fast:
            streams = read_bags(m, progress=progress)
        else:
            streams = [read_streams(s.bag, wrench_topics=m.wrench_topics.values(), joint_topic=m.joint_topic,
                                    joint_names=m.joint_names.values(), pose_topic=m.pose_topic, progress=progress, fast=False)
                       for s in m.recordings]
        read_s = time.perf_counter() - t0
        pose = streams[0].pose                                  # None: no pose topic, no message of it
        n_messages = (sum(len(st) for st in streams[0].wrench.values()) + (len(pose) if pose is not None else 0)
                      + len(streams[0].joints[m.joint_names[ds.robot.legs[0]]]))
        ingest_s, rows_out, err = np.nan, 0, np.nan
        if fast:
            t0 = time.perf_counter()
            got = ingest(m, progress=progress)
            ingest_s = time.perf_counter() - t0
            rec = got.dataset.recordings[0]
            rows_out = rec.n
            # the session epoch is the first stamp: t0 of the source
            src_rows = np.searchsorted(stand.t, rec.t + stand.t[0] - 1e-7)
            err = max(float(np.max(np.abs(rec.wrench[k] - stand.wrench[k][src_rows]))) for k in ds.robot.legs)
    return {
        "storage": storage,
        "n_poses": n_poses,
        "n_messages": int(n_messages),
        "n_rows": stand.n,
        "rows_out": rows_out,
        "write_s": round(write_s, 2),
        "read_s": round(read_s, 2),
        "ingest_s": round(ingest_s, 2),
        "messages_per_s": round(n_messages / (ingest_s if fast else read_s)),
        "max_wrench_error": err,
    }


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    n = int(argv[0]) if argv else 300
    for storage in argv[1:] or ["mcap", "ros1"]:
        print(bench_ingest(n, storage=storage, progress=None), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
