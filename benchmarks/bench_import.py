"""Benchmark: decode and import Velodyne captures (graphcal's parser and velodyne-decoder).

Cases: the real HDL-32E sample (monterey, 2702 packets, 872,800 returns) and a longer capture
made of `--repeat` copies of it, each copy's sensor timestamps moved on by the sample's span
(the same returns, one after the other). Each stage runs in its own process (its own peak
memory). Prints the figures and writes benchmarks/results/import.json.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import platform
import struct
import tempfile
import time
from pathlib import Path

from common import peak_gib, report, run_in_process

RESULTS = Path(__file__).resolve().parent / "results"
MONTEREY = Path(__file__).resolve().parents[2] / "shared/data/real/veloview_hdl32e_vlp16_pcap/monterey-first-100-packets.pcap"
_UDP_PAYLOAD_AT = 16 + 42  # record header + Ethernet/IPv4/UDP headers


def _repeated_capture(source: Path, copies: int, out: Path) -> None:
    """`copies` copies of a capture, the sensor timestamps of copy k moved on by k spans."""
    data = source.read_bytes()
    records, offset = [], 24
    while offset < len(data):
        length = struct.unpack_from("<I", data, offset + 8)[0]
        records.append(bytearray(data[offset:offset + 16 + length]))
        offset += 16 + length
    stamp_at = {1248: _UDP_PAYLOAD_AT + 1200, 554: _UDP_PAYLOAD_AT + 198}  # data / position packet timestamp
    stamps = [struct.unpack_from("<I", r, stamp_at[len(r) - 16])[0] for r in records if len(r) - 16 in stamp_at]
    span = max(stamps) - min(stamps) + 553
    with out.open("wb") as file:
        file.write(data[:24])
        for copy in range(copies):
            for record in records:
                at = stamp_at.get(len(record) - 16)
                if at is not None:
                    stamp = struct.unpack_from("<I", record, at)[0]
                    record = bytearray(record)
                    struct.pack_into("<I", record, at, (stamp + copy * span) % 3_600_000_000)
                file.write(record)


def _graphcal(path: str, queue) -> None:
    from graphcal.importers.velodyne_pcap import decode_pcap, import_pcap

    started = time.perf_counter()
    decoded = decode_pcap(path, quiet=True)
    decoded_s = time.perf_counter() - started
    started = time.perf_counter()
    recording = import_pcap(path, quiet=True)
    with tempfile.TemporaryDirectory() as tmp:
        recording.save(Path(tmp) / "rec")
        import_s = time.perf_counter() - started
    returns = len(decoded.returns["time_s"])
    queue.put({"returns": returns, "packets": decoded.n_data_packets, "graphcal_decode_s": decoded_s,
               "graphcal_returns_per_s": returns / decoded_s, "graphcal_import_and_save_s": import_s,
               "graphcal_peak_gib": peak_gib()})


def _velodyne_decoder(path: str, queue) -> None:
    import velodyne_decoder as vd

    config = vd.Config()
    config.model = vd.Model.HDL32E
    started = time.perf_counter()
    returns = sum(len(scan.points) for scan in vd.read_pcap(path, config))
    seconds = time.perf_counter() - started
    queue.put({"velodyne_decoder_s": seconds, "velodyne_decoder_returns": returns,
               "velodyne_decoder_returns_per_s": returns / seconds, "velodyne_decoder_peak_gib": peak_gib()})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=40, help="copies of the sample in the long capture")
    args = parser.parse_args()
    if not MONTEREY.is_file():
        raise SystemExit(f"{MONTEREY} is absent")
    results = {"benchmark": "import_velodyne_pcap", "cpus": mp.cpu_count(), "python": platform.python_version()}
    with tempfile.TemporaryDirectory() as tmp:
        long_capture = Path(tmp) / "long.pcap"
        _repeated_capture(MONTEREY, args.repeat, long_capture)
        for name, path in (("monterey", MONTEREY), (f"monterey_x{args.repeat}", long_capture)):
            figures = {"file_mib": path.stat().st_size / 2**20}
            figures.update(run_in_process(_graphcal, str(path)))
            figures.update(run_in_process(_velodyne_decoder, str(path)))
            results[name] = figures
    report(results, RESULTS / "import.json")


if __name__ == "__main__":
    main()
