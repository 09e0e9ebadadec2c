"""A bare ``.mcap`` file (Foxglove, the mcap CLI: no bag folder, no metadata.yaml) is a bag like its folder.

The same short sample window is written as a ROS 2 bag folder, then as a bare
file two ways: the folder's own MCAP file taken out of it, and the messages
re-written by the ``mcap`` library (as Foxglove and the mcap CLI write: its own
chunking, zstd, ``ros2msg`` schemas) in small chunks. Both must give the
folder's streams bit for bit, read chunk by chunk and through ``rosbags``, and
the same dataset when the ingest map names the file instead of the folder.
"""

import shutil
import tomllib

import numpy as np
import pytest
import tomli_w

from ftcal_nlp.ros import bagio, rawscan
from ftcal_nlp.ros.ingest import ingest

from test_ros import LEGS, _assert_same_streams, _bag_with, _forbid_rosbags_reader

TOPICS = dict(wrench_topics=[f"/ft/{k}/wrench" for k in LEGS], joint_topic="/joint_states",
              joint_names=[f"{k}_shaft" for k in LEGS], pose_topic="/mocap/body/pose")


def rewrite_with_mcap_library(folder, out, chunk_size=4096):
    """Every message of the bag folder, re-written into one bare MCAP file by the ``mcap`` library."""
    from mcap.writer import Writer
    from rosbags.highlevel import AnyReader

    with AnyReader([folder]) as reader, open(out, "wb") as f:
        w = Writer(f, chunk_size=chunk_size)
        w.start(profile="ros2", library="ftcal_nlp test (mcap library)")
        channels = {}
        for c in reader.connections:
            sid = w.register_schema(name=c.msgtype, encoding="ros2msg", data=c.msgdef.data.encode())
            channels[c.id] = w.register_channel(topic=c.topic, message_encoding="cdr", schema_id=sid)
        for c, t, raw in reader.messages():
            w.add_message(channels[c.id], log_time=t, data=bytes(raw), publish_time=t)
        w.finish()


@pytest.mark.parametrize("writer", ["folder_file", "mcap_library"])
def test_bare_mcap_reads_and_ingests_as_its_folder(tmp_path, monkeypatch, writer):
    mp = _bag_with(tmp_path, lambda *a: None, kind="standing")
    folder = tmp_path / "rec"
    bare = tmp_path / "session.mcap"
    if writer == "folder_file":
        shutil.copy(next(folder.glob("*.mcap")), bare)
    else:
        rewrite_with_mcap_library(folder, bare)
        assert len(rawscan.scan(bare).chunks) > 10  # many chunks, each with its index
    assert not (tmp_path / "metadata.yaml").exists()
    ref = bagio.read_streams(folder, **TOPICS)
    assert len(ref.wrench["/ft/FL/wrench"]) > 0 and ref.pose is not None
    with monkeypatch.context() as m:
        _forbid_rosbags_reader(m)
        _assert_same_streams(bagio.read_streams(bare, **TOPICS), ref)  # chunk by chunk
    _assert_same_streams(bagio.read_streams(bare, fast=False, **TOPICS), ref)  # through rosbags
    assert bagio.bag_topics(bare) == bagio.bag_topics(folder)

    d = tomllib.loads(mp.read_text())
    d["recording"][0]["bag"] = bare.name
    mp_bare = tmp_path / "map_bare.toml"
    mp_bare.write_bytes(tomli_w.dumps(d).encode())
    a, b = ingest(mp), ingest(mp_bare)
    assert a.epoch_ns == b.epoch_ns and [r.name for r in a.dataset.recordings] == [r.name for r in b.dataset.recordings]
    for ra, rb in zip(a.dataset.recordings, b.dataset.recordings):
        np.testing.assert_array_equal(ra.t, rb.t)
        np.testing.assert_array_equal(ra.quat, rb.quat)
        for k in LEGS:
            np.testing.assert_array_equal(ra.wrench[k], rb.wrench[k])
            np.testing.assert_array_equal(ra.phi[k], rb.phi[k])


def test_a_file_neither_bag_nor_mcap_is_named(tmp_path):
    f = tmp_path / "session.db3x"
    f.write_bytes(b"\x89MCAP0\r\n")
    with pytest.raises(bagio.BagError, match=r"session.db3x: a file not named \*.bag or \*.mcap"):
        bagio.read_streams(f, wrench_topics=[])
    bad = tmp_path / "broken.mcap"
    bad.write_bytes(b"not an mcap file at all")
    with pytest.raises(bagio.BagError, match=r"broken.mcap"):
        bagio.read_streams(bad, wrench_topics=[])
