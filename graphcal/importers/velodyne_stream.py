"""Velodyne data packets decoded chunk after chunk, each return as the whole capture decoded at once would give it.

A packet's returns need its successor (the azimuth and time its field-of-view gaps are timed back from:
velodyne_packets.gap_us), so the last packet of each chunk is held back and decoded with the next chunk; the hour
of the timestamps and the revolution index carry over from chunk to chunk, and the spin rate's median is kept as
counts of its distinct values. Memory holds one chunk of packets and its returns.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from graphcal.importers.nmea import RmcFix
from graphcal.importers.value_counts import ValueCounts
from graphcal.importers.velodyne_packets import (
    PACKET,
    HourUnwrap,
    PacketLayout,
    RevolutionCounter,
    decode_returns,
    packet_rates,
)
from graphcal.recording.points import concatenated_columns


@dataclass(frozen=True)
class VelodyneCapture:
    """What holds for a whole capture's returns.

    rotation_hz: median spin rate [Hz]; fixes: (sensor time s past the first packet's hour, RMC fix) of every
    position packet with a fix; host_hour_utc_s: top of that hour by the capture host clock [s since 1970 UTC];
    distance_m: the packets' distance unit [m]."""

    path: Path
    model: str
    dual_return: bool
    rotation_hz: float
    interpolated_azimuth: bool = True
    fixes: list[tuple[float, RmcFix]] = field(default_factory=list)
    host_hour_utc_s: float = 0.0
    n_data_packets: int = 0
    n_other_packets: int = 0
    cut_bytes: int = 0
    distance_m: float = 0.002


class PacketDecoder:
    """Returns of consecutive data packets given chunk after chunk (velodyne_packets.decode_returns): `add` gives
    those of every packet but the last one given so far, `finish` those of the last."""

    def __init__(self, layout: PacketLayout, dual: bool, distance_m: float, interpolate_azimuth: bool):
        self._layout, self._dual, self._distance_m = layout, dual, distance_m
        self._interpolate = interpolate_azimuth
        self._unwrap, self._revolutions, self._rates = HourUnwrap(), RevolutionCounter(), ValueCounts()
        self._held: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # packet, time [us], revolution

    def add(self, packets: np.ndarray) -> dict[str, np.ndarray]:
        time_us, scan = self._unwrap(packets["stamp_us"]), self._revolutions(packets)
        if self._held is not None:
            held_packet, held_us, held_scan = self._held
            packets = np.concatenate([held_packet, packets])
            time_us, scan = np.concatenate([held_us, time_us]), np.concatenate([held_scan, scan])
        if not len(packets):
            return self._decode(packets, time_us, scan, time_us, time_us)
        self._held = (packets[-1:], time_us[-1:], scan[-1:])
        next_azimuth = packets["blocks"]["azimuth"][1:, 0].astype(np.float64)
        return self._decode(packets[:-1], time_us[:-1], scan[:-1], time_us[1:], next_azimuth)

    def finish(self) -> dict[str, np.ndarray]:
        if self._held is None:
            return self.add(np.zeros(0, dtype=PACKET))
        (packet, time_us, scan), self._held = self._held, None
        unknown = np.full(1, np.nan)  # no successor
        return self._decode(packet, time_us, scan, unknown, unknown)

    def rotation_hz(self) -> float:
        """Median spin rate of the packets decoded [Hz]: each packet's azimuth advance over its firing time."""
        return float(np.round(self._rates.median() * 1e6 / 36000.0, 3))

    def _decode(self, packets, time_us, scan, next_us, next_azimuth) -> dict[str, np.ndarray]:
        self._rates.add(packet_rates(packets, self._layout, self._dual))
        return decode_returns(packets, self._layout, self._dual, time_us, scan, self._distance_m, self._interpolate,
                              (next_us, next_azimuth))


def decoded_returns(decoder: PacketDecoder, chunks: Iterable[np.ndarray]) -> Iterator[dict[str, np.ndarray]]:
    """The returns of each chunk of packets (the last packet's with the last chunk), in packet/block/channel order:
    time_s (s past the first packet's hour), fibre, range [m], azimuth [rad], intensity, scan."""
    for packets in chunks:
        yield decoder.add(packets)
    yield decoder.finish()


def time_sorted(returns: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Returns sorted by time_s (stable: equal times keep their packet order)."""
    if not np.any(np.diff(returns["time_s"]) < 0):  # HDL-64E blocks, dual returns: equal times, other order
        return returns
    order = np.argsort(returns["time_s"], kind="stable")
    return {name: values[order] for name, values in returns.items()}


def all_returns(decoder: PacketDecoder, chunks: Iterable[np.ndarray]) -> dict[str, np.ndarray]:
    """Every return of the chunks in one set of arrays, sorted by time_s (a capture small enough to hold)."""
    return time_sorted(concatenated_columns(list(decoded_returns(decoder, chunks))))
