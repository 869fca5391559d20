"""Velodyne data packets (HDL-32E, VLP-16, HDL-64E) -> raw returns: distance, encoder azimuth, time.

A data packet is 1206 bytes (HDL-32E/VLP-16 user manuals, "Data Packet Format"): 12 blocks of
[flag uint16 (0xEEFF; 0xDDFF for the HDL-64E lower block), azimuth uint16 in 0.01 deg,
32 x (distance uint16 in 2 mm, intensity uint8)], then a uint32 timestamp in microseconds past
the top of the hour, the return-mode byte (0x37 strongest, 0x38 last, 0x39 dual) and the
product byte (0x21 HDL-32E, 0x22 VLP-16; HDL-64E writes status bytes there).

The block azimuth is the encoder reading at the block's first firing. Each laser fires later
(the firing-time tables below), while the head keeps turning; its encoder azimuth is
interpolated to its own firing time with the packet's mean rotation rate (first to last block),
as the manuals' "precision azimuth" recipe and velodyne-decoder do, but without rounding to
0.01 deg. `interpolate_azimuth=False` gives every laser of a firing sequence the azimuth of the
sequence's start: the block azimuth, plus half a block step for the VLP-16's second sequence
(VeloView 3.x, the old ROS HDL-32E driver).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PACKET_BYTES = 1206
UPPER_BLOCK, LOWER_BLOCK = 0xEEFF, 0xDDFF
DUAL_RETURN_MODE = 0x39
PRODUCT_IDS = {0x21: "HDL-32E", 0x22: "VLP-16"}

_RETURN = np.dtype([("distance", "<u2"), ("intensity", "u1")])
_BLOCK = np.dtype([("flag", "<u2"), ("azimuth", "<u2"), ("returns", _RETURN, (32,))])
PACKET = np.dtype([("blocks", _BLOCK, (12,)), ("stamp_us", "<u4"), ("return_mode", "u1"), ("product", "u1")])
assert PACKET.itemsize == PACKET_BYTES


@dataclass(frozen=True)
class PacketLayout:
    """How one sensor model fills a packet.

    column_us: duration of one firing column (every laser fired once; two VLP-16 firing
    sequences per block); blocks_per_column: blocks one column fills in single-return mode
    (HDL-64E: upper + lower block).
    """

    model: str
    n_lasers: int
    column_us: float
    blocks_per_column: int

    def packet_us(self, dual: bool) -> float:
        """Time between two consecutive packets [us]."""
        return 12 / (self.blocks_per_column * (2 if dual else 1)) * self.column_us

    def timing_us(self, dual: bool) -> np.ndarray:
        """(12, 32) firing time of each block/channel after the packet timestamp [us]."""
        block, channel = np.arange(12)[:, None], np.arange(32)[None, :]
        if self.model == "HDL-32E":
            # HDL-32E manual: 1.152 us between lasers, a firing cycle every 46.08 us
            return (block // (2 if dual else 1)) * 46.08 + channel * 1.152
        if self.model == "VLP-16":
            # VLP-16 manual, "Precision azimuth calculation": two 55.296 us firing sequences per
            # block, lasers 2.304 us apart
            column = block // (2 if dual else 1)
            return (2 * column + channel // 16) * 55.296 + (channel % 16) * 2.304
        # HDL-64E S2 manual, laser firing time table (as in velodyne-decoder): upper and lower
        # block fire together every 48 us, four lasers at 0/1.26/2.46/3.66 us every 6 us
        column = block // (4 if dual else 2)
        pattern = np.array([0.0, 1.26, 2.46, 3.66])
        return column * 48.0 + (channel // 4) * 6.0 + pattern[channel % 4]

    def sequence_start_us(self) -> np.ndarray:
        """(32,) start of each channel's firing sequence after its block's first firing [us]
        (the VLP-16's second sequence starts 55.296 us into the block)."""
        channel = np.arange(32)
        return (channel // 16) * 55.296 if self.model == "VLP-16" else np.zeros(32)

    def dual_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Dual-return mode: the blocks holding one firing's first and second returns (block indices)."""
        first = np.array([0, 1, 4, 5, 8, 9]) if self.model == "HDL-64E" else np.arange(0, 12, 2)
        return first, first + (2 if self.model == "HDL-64E" else 1)

    def laser_ids(self, flags: np.ndarray) -> np.ndarray:
        """(n, 12, 32) laser id (row of sensor.yaml) of every channel, from the (n, 12) block flags."""
        channel = np.arange(32)[None, None, :]
        if self.model == "VLP-16":
            return np.broadcast_to(channel % 16, flags.shape + (32,))
        if self.model == "HDL-64E":
            return channel + 32 * (flags == LOWER_BLOCK)[:, :, None]
        return np.broadcast_to(channel, flags.shape + (32,))


LAYOUTS = {
    "HDL-32E": PacketLayout("HDL-32E", 32, column_us=46.08, blocks_per_column=1),
    "VLP-16": PacketLayout("VLP-16", 16, column_us=2 * 55.296, blocks_per_column=1),
    "HDL-64E": PacketLayout("HDL-64E", 64, column_us=48.0, blocks_per_column=2),
}


def unwrap_hour_us(stamp_us: np.ndarray) -> np.ndarray:
    """Microseconds past the top of the hour -> microseconds past the first stamp's hour (float64)."""
    stamp = np.asarray(stamp_us, dtype=np.float64)
    wraps = np.concatenate([[0.0], np.cumsum(np.diff(stamp) < -1800e6)])
    return stamp + 3600e6 * wraps


def revolution_counter(packets: np.ndarray) -> np.ndarray:
    """(n, 12) revolution index of each block: +1 each time the block azimuth decreases (wraps)."""
    azimuth = packets["blocks"]["azimuth"].astype(np.int64).ravel()
    return np.concatenate([[0], np.cumsum(np.diff(azimuth) < 0)]).reshape(-1, 12).astype(np.int32)


def returned(packets: np.ndarray, layout: PacketLayout, dual: bool) -> np.ndarray:
    """(n, 12, 32) mask of the returns kept: distance 0 is "no return", and in dual-return mode a
    second return equal to the first (same distance and intensity) is the same return twice."""
    returns = packets["blocks"]["returns"]
    kept = returns["distance"] > 0
    if dual:
        first, second = layout.dual_pairs()
        same = ((returns["distance"][:, second] == returns["distance"][:, first])
                & (returns["intensity"][:, second] == returns["intensity"][:, first]))
        kept[:, second] &= ~same
    return kept


def packet_rates(packets: np.ndarray, layout: PacketLayout, dual: bool) -> np.ndarray:
    """(n,) spin rate of each packet [0.01 deg / us]: its azimuth advance from the first to the
    last block over their firing times."""
    timing = layout.timing_us(dual)
    azimuth = packets["blocks"]["azimuth"].astype(np.float64)
    return np.mod(azimuth[:, -1] - azimuth[:, 0], 36000.0) / (timing[-1, 0] - timing[0, 0])


def decode_returns(packets: np.ndarray, layout: PacketLayout, dual: bool, time_us: np.ndarray,
                   scan: np.ndarray, distance_m: float = 0.002, interpolate_azimuth: bool = True) -> dict:
    """Raw returns of packets (structured PACKET array), those `returned` keeps.

    time_us: (n,) packet timestamps, unwrapped past the hour; scan: (n, 12) revolution index.
    The rotation rate is each packet's mean: its azimuth advance from the first to the last block.
    Returns arrays in packet/block/channel order: time_s (float64, s past the hour), fibre,
    range [m], azimuth [rad, encoder, clockwise, wrapped to [0, 2 pi)], intensity, scan.
    """
    blocks = packets["blocks"]
    timing = layout.timing_us(dual)
    distance = blocks["returns"]["distance"]
    valid = returned(packets, layout, dual)
    block_azimuth = blocks["azimuth"].astype(np.float64)
    rate = packet_rates(packets, layout, dual)
    after_block_us = (timing - timing[:, :1]) if interpolate_azimuth else layout.sequence_start_us()[None, :]
    azimuth = block_azimuth[:, :, None] + rate[:, None, None] * after_block_us[None]
    return {
        "time_s": (time_us[:, None, None] + timing[None])[valid] * 1e-6,
        "fibre": layout.laser_ids(blocks["flag"])[valid].astype(np.int16),
        "range": (distance[valid] * distance_m).astype(np.float32),
        "azimuth": np.radians(np.mod(azimuth[valid], 36000.0) / 100.0).astype(np.float32),
        "intensity": blocks["returns"]["intensity"][valid].astype(np.float32),
        "scan": np.broadcast_to(scan[:, :, None], distance.shape)[valid],
    }
