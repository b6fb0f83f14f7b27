#!/usr/bin/env python3
"""An independent ROS 2 subscriber to risd's clouds (not RIS code): it sees the node and its
publishers in rmw_zenoh's liveliness tokens, subscribes to their key expressions, starts one
scan, and decodes every PointCloud2 with the `rosbags` package's CDR deserialiser. Each message
is checked against the PLY that risd wrote for the same cloud: same points (metres vs mm), an
organised sensor cloud at its camera pixels; re-serialising it with rosbags gives the received
bytes exactly; the attachment (Zenoh serialisation: int64 sequence, int64 timestamp, 16-byte
gid) is decoded with eclipse-zenoh's own deserialiser.

usage: ros2_client.py ENDPOINT CELL DATA_DIR SENSOR...
Prints one JSON summary line; exits non-zero on the first failed check.
"""
import json
import sys
import threading
import time

import numpy as np
import zenoh
import zenoh.ext as zext
from rosbags.typesys import Stores, get_typestore

TYPE = "sensor_msgs/msg/PointCloud2"
DDS = "sensor_msgs::msg::dds_::PointCloud2_"


def read_ply(path):
    """A binary little-endian PLY's vertex table as a numpy structured array."""
    data = open(path, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    types = {"float": "<f4", "double": "<f8", "uchar": "u1", "uint": "<u4", "int": "<i4"}
    fields, count, info = [], 0, {}
    for line in data[:end].decode().splitlines():
        f = line.split()
        if f[:2] == ["element", "vertex"]:
            count = int(f[2])
        elif f[0] == "property":
            fields.append((f[2], types[f[1]]))
        elif f[0] == "obj_info":
            info[f[1]] = int(f[2])
    return np.frombuffer(data, dtype=np.dtype(fields), count=count, offset=end), info


def main():
    endpoint, cell, data_dir, sensors = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]
    store = get_typestore(Stores.ROS2_JAZZY)
    type_hash = store.hash_rihs01(TYPE)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    session = zenoh.open(conf)

    # The ROS 2 graph as rmw_zenoh sees it.
    tokens = [r.ok.key_expr.__str__() for r in session.liveliness().get("@ros2_lv/0/**") if r.ok]
    nodes = [t for t in tokens if "/NN/" in t]
    pubs = [t for t in tokens if "/MP/" in t]
    assert any(t.endswith("/%ris/risd") for t in nodes), tokens
    clouds = sensors + ["merged"]
    for c in clouds:
        topic = f"%ris%{cell}%{c}%points"
        match = [p for p in pubs if f"/{topic}/{DDS}/{type_hash}/" in p]
        assert len(match) == 1, (c, pubs)

    received, lock, done = {}, threading.Lock(), threading.Event()

    def on_sample(sample):
        key = str(sample.key_expr)
        with lock:
            received.setdefault(key, []).append(
                (sample.payload.to_bytes(), sample.attachment.to_bytes() if sample.attachment else None)
            )
            if len(received) == len(clouds):
                done.set()

    keys = {c: f"0/ris/{cell}/{c}/points/{DDS}/{type_hash}" for c in clouds}
    subs = [session.declare_subscriber(k, on_sample) for k in keys.values()]

    reply = next(iter(session.get(f"ris/{cell}/scan", payload=json.dumps({}))))
    scan_id = json.loads(reply.ok.payload.to_bytes())["scan_id"]
    assert done.wait(240), f"received {list(received)} of {list(keys.values())}"
    time.sleep(0.5)

    summary = {"scan_id": scan_id, "type_hash": type_hash, "clouds": {}}
    for c in clouds:
        msgs = received[keys[c]]
        assert len(msgs) == 1, (c, len(msgs))
        payload, attachment = msgs[0]
        msg = store.deserialize_cdr(payload, TYPE)
        again = bytes(store.serialize_cdr(msg, TYPE))
        assert again == payload, f"{c}: rosbags re-serialises {len(again)} bytes, received {len(payload)}"
        names = [(f.name, f.offset, f.datatype, f.count) for f in msg.fields]
        assert names == [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("confidence", 12, 7, 1)], names
        assert not msg.is_bigendian and msg.point_step == 16 and msg.row_step == 16 * msg.width
        seq, stamp_ns, gid = zext.z_deserialize(tuple[zext.Int64, zext.Int64, bytes], zenoh.ZBytes(attachment))
        assert len(gid) == 16 and seq >= 1, (seq, gid)
        assert abs(stamp_ns / 1e9 - time.time()) < 300, stamp_ns
        assert abs(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 - stamp_ns / 1e9) < 1e-6

        pts = np.frombuffer(bytes(msg.data), dtype=np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("c", "<f4")]))
        assert len(pts) == msg.width * msg.height
        ply, info = read_ply(f"{data_dir}/scans/{scan_id}/{c}.ply")
        if c == "merged":
            assert msg.height == 1 and msg.is_dense, (msg.height, msg.is_dense)
            at = np.arange(len(ply))
        else:
            assert (msg.width, msg.height) == (info["num_cols"], info["num_rows"]), (c, msg.width, msg.height, info)
            assert not msg.is_dense
            at = ply["row"].astype(np.int64) * msg.width + ply["column"]
        finite = np.isfinite(pts["x"])
        assert finite.sum() == len(ply), (c, int(finite.sum()), len(ply))
        err = max(
            float(np.max(np.abs(pts[a][at] * 1000.0 - ply[a]))) for a in ("x", "y", "z")
        )
        assert err < 1e-3, f"{c}: {err} mm"
        assert np.array_equal(pts["c"][at], ply["confidence"])
        summary["clouds"][c] = {
            "frame_id": msg.header.frame_id,
            "width": msg.width,
            "height": msg.height,
            "points": int(finite.sum()),
            "max_error_mm": err,
            "sequence": seq,
            "gid": gid.hex(),
        }
    for s in subs:
        s.undeclare()
    session.close()
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
