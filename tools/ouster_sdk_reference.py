"""Reference values for tests/test_importers_ouster.py, computed with ouster-sdk (the test oracle).

ouster-sdk cannot share graphcal's environment (it pins older click, psutil and rosbags), so run
this in a venv of its own:
    python3.11 -m venv /tmp/ouster-venv && /tmp/ouster-venv/bin/pip install ouster-sdk==1.0.1
    /tmp/ouster-venv/bin/python tools/ouster_sdk_reference.py ../shared/data/real/ouster_sdk_pcaps \
        tests/data/ouster_sdk_reference.npz
It writes, for each real capture, a sample of returns (frame index in the file, beam row, column,
range mm, reflectivity, column timestamp ns) with the SDK's sensor-frame xyz [m] (XYZLut), and,
for the LEGACY and RNG19_RFL8_SIG16_NIR16 profiles, the first two packets the SDK encodes
(frame_to_packets) from the OS-1 capture's second frame, with the values they hold.
"""

import sys
from pathlib import Path

import numpy as np
from ouster.sdk import core, pcap

CAPTURES = {"os1": ("OS-1-128_v2.3.0_1024x10_lb_n3.pcap", "OS-1-128_v2.3.0_1024x10.json"),
            "os0": ("OS-0-128-U1_v2.3.0_1024x10.pcap", "OS-0-128-U1_v2.3.0_1024x10.json")}
STEP = 61  # every STEP-th return of a frame is kept


def frames(folder: Path, key: str):
    capture, meta = CAPTURES[key]
    source = pcap.PcapFrameSetSource(str(folder / capture), meta=[str(folder / meta)])
    return source.sensor_info[0], [frame_set[0] for frame_set in source]


def sampled(info, frame_list) -> dict:
    lut = core.XYZLut(info)
    out = {name: [] for name in ("frame", "row", "column", "range_mm", "reflectivity", "timestamp_ns", "xyz")}
    for index, frame in enumerate(frame_list):
        rng = frame.field("RANGE")
        row, column = np.nonzero(rng)
        keep = slice(index, None, STEP)
        row, column = row[keep], column[keep]
        out["frame"].append(np.full(len(row), index))
        out["row"].append(row)
        out["column"].append(column)
        out["range_mm"].append(rng[row, column])
        out["reflectivity"].append(frame.field("REFLECTIVITY")[row, column])
        out["timestamp_ns"].append(frame.timestamp[column])
        out["xyz"].append(lut(frame)[row, column])
    return {name: np.concatenate(values) for name, values in out.items()}


def encoded(info, frame, profile: str) -> dict:
    """The first two packets of `frame` encoded in `profile`, and what they hold."""
    info = core.SensorInfo(info.to_json_string())
    info.format.udp_profile_lidar = getattr(core.UDPProfileLidar, profile)
    other = core.LidarFrame(info)
    for name in ("RANGE", "REFLECTIVITY"):
        other.field(name)[:] = frame.field(name)
    other.timestamp[:] = frame.timestamp
    other.measurement_id[:] = frame.measurement_id
    other.status[:] = frame.status
    other.frame_id = frame.frame_id
    packets = core.frame_to_packets(other, core.PacketFormat(info), info.init_id, info.sn)
    columns = 2 * info.format.columns_per_packet
    return {"packets": np.stack([np.asarray(p.buf, dtype=np.uint8) for p in packets[:2]]),
            "range_mm": other.field("RANGE")[:, :columns].T.copy(),
            "reflectivity": other.field("REFLECTIVITY")[:, :columns].T.copy(),
            "timestamp_ns": other.timestamp[:columns].copy(), "measurement_id": other.measurement_id[:columns].copy(),
            "frame_id": np.array(other.frame_id)}


def main(folder: str, out: str) -> None:
    arrays = {}
    for key in CAPTURES:
        info, frame_list = frames(Path(folder), key)
        arrays |= {f"{key}_{name}": values for name, values in sampled(info, frame_list).items()}
        arrays[f"{key}_returns_per_frame"] = np.array([np.count_nonzero(f.field("RANGE")) for f in frame_list])
        if key == "os1":
            for profile in ("LEGACY", "RNG19_RFL8_SIG16_NIR16"):
                arrays |= {f"{profile}_{name}": values for name, values in encoded(info, frame_list[1], profile).items()}
    np.savez_compressed(out, **arrays)


if __name__ == "__main__":
    main(*sys.argv[1:3])
