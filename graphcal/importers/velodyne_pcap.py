"""Velodyne pcap (HDL-32E, VLP-16, HDL-64E, VLP-32C, VLS-128) -> a recording (graphcal-recording/1), streamed.

The libpcap file is read twice, chunk_bytes at a time. A light first pass surveys the data packets (model, return
mode, the hour of their timestamps: velodyne_survey) and reads the $GPRMC fixes of the position packets; the second
decodes the data packets chunk by chunk (velodyne_stream: range = raw distance x 2 or 4 mm, encoder azimuth
interpolated to each firing, laser id, time = packet timestamp + the firing-time table) into points.parquet
(velodyne_recording: nominal sensor model, GPS seconds of week, trajectory). Memory holds a chunk of the file and
its returns, whatever the capture's length. docs/howto/import.md has the details.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError
from graphcal.common.progress import progress
from graphcal.importers.nmea import RmcFix, find_rmc
from graphcal.importers.pcap import UdpPayloads, chunk_count, udp_payload_chunks
from graphcal.importers.velodyne_calibration import VelodyneCalibration
from graphcal.importers.velodyne_packets import PACKET, PACKET_BYTES
from graphcal.importers.velodyne_recording import (
    SurveyedCapture,
    VelodyneReturns,
    decoded_capture,
    surveyed_capture,
    write_velodyne_recording,
)
from graphcal.importers.velodyne_survey import PacketSurvey
from graphcal.recording.directory import Recording
from graphcal.recording.extrinsic import Extrinsic
from graphcal.recording.trajectory import Trajectory

DATA_PORT, POSITION_PORT = 2368, 8308
POSITION_PACKET_BYTES = 512
CHUNK_BYTES = 2**20  # libpcap bytes read at a time: about 830 data packets, 0.3 M returns
_POSITION_STAMP_AT = 198  # uint32 us past the hour in a position packet (HDL-32E / VLP-16 manuals)


def import_pcap(path: str | Path, out: str | Path, *, model: str | None = None,
                calibration: VelodyneCalibration | None = None, trajectory: Trajectory | None = None,
                position: tuple[float, float, float] | None = None,
                attitude_deg: tuple[float, float, float] = (0.0, 0.0, 0.0), extrinsic: Extrinsic | None = None,
                interpolate_azimuth: bool = True, crs: str = "auto", name: str | None = None,
                chunk_bytes: int = CHUNK_BYTES, quiet: bool = False) -> Recording:
    """A Velodyne capture as the recording folder `out` (written whole or not at all; an existing folder is
    replaced), times in GPS seconds of week; options as velodyne_recording.write_velodyne_recording. model forces
    one of velodyne_packets.LAYOUTS (else detected); chunk_bytes: how much of the file is read at a time."""
    surveyed = survey_pcap(path, model, calibration.distance_resolution_m if calibration else None,
                           interpolate_azimuth, chunk_bytes, quiet)
    return write_velodyne_recording(surveyed, out, "velodyne-pcap", calibration=calibration, trajectory=trajectory,
                                    position=position, attitude_deg=attitude_deg, extrinsic=extrinsic, crs=crs,
                                    name=name)


def decode_pcap(path: str | Path, model: str | None = None, distance_resolution_m: float | None = None,
                interpolate_azimuth: bool = True, chunk_bytes: int = CHUNK_BYTES,
                quiet: bool = False) -> VelodyneReturns:
    """Every raw return of a Velodyne capture in memory (a capture small enough to hold); arguments as
    survey_pcap."""
    return decoded_capture(survey_pcap(path, model, distance_resolution_m, interpolate_azimuth, chunk_bytes, quiet))


def survey_pcap(path: str | Path, model: str | None = None, distance_resolution_m: float | None = None,
                interpolate_azimuth: bool = True, chunk_bytes: int = CHUNK_BYTES,
                quiet: bool = False) -> SurveyedCapture:
    """A Velodyne capture surveyed (its first pass), ready to decode. model forces one of velodyne_packets.LAYOUTS
    (else detected); distance_resolution_m: an HDL-64E's packet distance unit from its calibration."""
    path = Path(path)
    survey, fixes = PacketSurvey(), _PositionFixes()
    n_records = n_other = cut_bytes = 0
    for udp in progress(udp_payload_chunks(path, chunk_bytes), f"surveying {path.name}",
                        total=chunk_count(path, chunk_bytes), quiet=quiet):
        cut = (udp.port == DATA_PORT) & (udp.length < PACKET_BYTES)
        if cut.any():
            first = int(np.flatnonzero(cut)[0])
            raise RecordingError(path, f"record {udp.record[first]}: data packet of {udp.length[first]} bytes",
                                 expected=f"{PACKET_BYTES}-byte Velodyne data packets (captured with a snap length "
                                          "too short?)")
        is_data = udp.length == PACKET_BYTES
        is_position = (udp.length == POSITION_PACKET_BYTES) & (udp.port == POSITION_PORT)
        time_us = survey.add(_data_packets(udp, is_data), udp.time_s[is_data], udp.record[is_data])
        fixes.add(udp.stack(is_position, POSITION_PACKET_BYTES), udp.record[is_position], udp.record[is_data],
                  time_us)
        n_records += udp.n_records
        n_other += int((~is_data & ~is_position).sum()) + udp.n_records - len(udp.record)
        cut_bytes = udp.cut_bytes
    if not survey.n_packets:
        raise RecordingError(path, f"no Velodyne data packet among {n_records} records",
                             expected=f"UDP payloads of {PACKET_BYTES} bytes (port {DATA_PORT})")

    def packets() -> Iterator[np.ndarray]:
        for udp in progress(udp_payload_chunks(path, chunk_bytes), f"decoding {path.name}",
                            total=chunk_count(path, chunk_bytes), quiet=quiet):
            yield _data_packets(udp, udp.length == PACKET_BYTES)

    return surveyed_capture(survey, packets, path=path, model=model, distance_resolution_m=distance_resolution_m,
                            interpolate_azimuth=interpolate_azimuth, fixes=fixes.fixes, n_other_packets=n_other,
                            cut_bytes=cut_bytes)


def _data_packets(udp: UdpPayloads, is_data: np.ndarray) -> np.ndarray:
    """The data packets of a chunk as a structured PACKET array."""
    return udp.stack(is_data, PACKET_BYTES).view(PACKET).ravel()


class _PositionFixes:
    """The $GPRMC fixes of the position packets, (sensor time s past the first data packet's hour, fix), from the
    position packets and data packets of chunk after chunk: each position timestamp is put in the hour of the data
    packet before it (the first data packet for those before any)."""

    def __init__(self):
        self.fixes: list[tuple[float, RmcFix]] = []
        self._waiting: list[np.ndarray] = []  # position packets before the first data packet
        self._last_us: float | None = None  # timestamp of the last data packet so far [us past the first's hour]

    def add(self, positions: np.ndarray, position_records: np.ndarray, data_records: np.ndarray,
            time_us: np.ndarray) -> None:
        """positions: (n, 512) position packets; their records, the data packets' records and timestamps [us]."""
        if self._last_us is None and not len(time_us):
            self._waiting.append(positions)
            return
        before = np.searchsorted(data_records, position_records)  # data packets of the chunk before each
        if self._last_us is None:  # the first data packet is in this chunk
            positions = np.concatenate([*self._waiting, positions])
            before = np.concatenate([np.zeros(len(positions) - len(before), dtype=np.int64),
                                     np.maximum(before - 1, 0)])
            reference_us, self._waiting = time_us, []
        else:
            reference_us = np.concatenate([[self._last_us], time_us])
        if len(time_us):
            self._last_us = float(time_us[-1])
        stamps = positions[:, _POSITION_STAMP_AT:_POSITION_STAMP_AT + 4].copy().view("<u4").ravel().astype(np.float64)
        stamps += 3600e6 * np.round((reference_us[before] - stamps) / 3600e6)
        for row, stamp_us in zip(positions, stamps):
            fix = find_rmc(row.tobytes())
            if fix is not None:
                self.fixes.append((stamp_us * 1e-6, fix))
