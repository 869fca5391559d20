"""Benchmark: import and decode Velodyne captures (graphcal's parser and velodyne-decoder).

Cases: the real HDL-32E sample (monterey, 2702 packets, 872,800 returns) and longer captures made
of `--repeat` copies of it, each copy's sensor timestamps moved on by the sample's span (the same
returns, one after the other). Stages, each in its own process (its own peak memory): graphcal's
import into a recording folder (streamed: its peak should not grow with the capture), graphcal's
decode of every return into arrays held in memory (decode_pcap), velodyne-decoder's read. Prints
the figures and writes benchmarks/results/import.json with the machine and the date.
"""

from __future__ import annotations

import argparse
import datetime
import struct
import tempfile
import time
from pathlib import Path

from common import machine, peak_gib, report, run_in_process

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


def _graphcal_import(path: str, queue) -> None:
    from graphcal.importers.velodyne_pcap import import_pcap

    with tempfile.TemporaryDirectory() as tmp:
        started = time.perf_counter()
        recording = import_pcap(path, Path(tmp) / "rec", quiet=True)
        seconds = time.perf_counter() - started
        returns = len(recording.points)
    queue.put({"returns": returns, "graphcal_import_s": seconds, "graphcal_import_returns_per_s": returns / seconds,
               "graphcal_import_peak_gib": peak_gib()})


def _graphcal_decode(path: str, queue) -> None:
    from graphcal.importers.velodyne_pcap import decode_pcap

    started = time.perf_counter()
    decoded = decode_pcap(path, quiet=True)
    seconds = time.perf_counter() - started
    returns = len(decoded.returns["time_s"])
    queue.put({"packets": decoded.n_data_packets, "graphcal_decode_s": seconds,
               "graphcal_decode_returns_per_s": returns / seconds, "graphcal_decode_peak_gib": peak_gib()})


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
    parser.add_argument("--repeat", type=int, nargs="+", default=[5, 20, 40],
                        help="copies of the sample in each longer capture")
    args = parser.parse_args()
    if not MONTEREY.is_file():
        raise SystemExit(f"{MONTEREY} is absent")
    results = {"benchmark": "import_velodyne_pcap",
               "machine": machine(),
               "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
    with tempfile.TemporaryDirectory() as tmp:
        cases = {"monterey": MONTEREY}
        for copies in args.repeat:
            cases[f"monterey_x{copies}"] = Path(tmp) / f"x{copies}.pcap"
            _repeated_capture(MONTEREY, copies, cases[f"monterey_x{copies}"])
        for name, path in cases.items():
            figures = {"file_mib": path.stat().st_size / 2**20}
            for stage in (_graphcal_import, _graphcal_decode, _velodyne_decoder):
                figures.update(run_in_process(stage, str(path)))
            results[name] = figures
    report(results, RESULTS / "import.json")


if __name__ == "__main__":
    main()
