"""Velodyne data packets (HDL-32E, VLP-16, HDL-64E, VLP-32C, VLS-128) -> raw returns: distance,
encoder azimuth, time.

A data packet is 1206 bytes (the user manuals' "Data Packet Format"): 12 blocks of
[flag uint16, azimuth uint16 in 0.01 deg, 32 x (distance uint16, intensity uint8)], then a uint32
timestamp in microseconds past the top of the hour, the return-mode byte (0x37 strongest, 0x38
last, 0x39 dual) and the product byte (0x21 HDL-32E, 0x22 VLP-16, 0x28 VLP-32C, 0xA1 VLS-128;
HDL-64E writes status bytes there). The flag names the block's bank of 32 lasers: 0xEEFF, 0xDDFF
(HDL-64E lower block, VLS-128 second bank), 0xCCFF and 0xBBFF (VLS-128 third and fourth banks).
The distance unit is 2 mm (HDL-32E, VLP-16, HDL-64E) or 4 mm (VLP-32C, VLS-128).

The block azimuth is the encoder reading at the first firing of the block's column (the VLS-128's
four banks of one firing sequence carry the same azimuth). Each laser fires later (the
firing-time tables below), while the head keeps turning; its encoder azimuth is interpolated to
its own firing time with the packet's mean rotation rate (first to last block), as the manuals'
"precision azimuth" recipe and velodyne-decoder do, but without rounding to 0.01 deg.
`interpolate_azimuth=False` gives every laser of a firing sequence the azimuth of the sequence's
start: the block azimuth, plus half a block step for the VLP-16's second sequence (VeloView 3.x,
the old ROS HDL-32E driver).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PACKET_BYTES = 1206
UPPER_BLOCK, LOWER_BLOCK = 0xEEFF, 0xDDFF
BANK_FLAGS = (0xEEFF, 0xDDFF, 0xCCFF, 0xBBFF)  # bank 0..3 of 32 lasers (HDL-64E: 0 and 1; VLS-128: 0..3)
DUAL_RETURN_MODE = 0x39
PRODUCT_IDS = {0x21: "HDL-32E", 0x22: "VLP-16", 0x28: "VLP-32C", 0xA1: "VLS-128"}

_RETURN = np.dtype([("distance", "<u2"), ("intensity", "u1")])
_BLOCK = np.dtype([("flag", "<u2"), ("azimuth", "<u2"), ("returns", _RETURN, (32,))])
PACKET = np.dtype([("blocks", _BLOCK, (12,)), ("stamp_us", "<u4"), ("return_mode", "u1"), ("product", "u1")])
assert PACKET.itemsize == PACKET_BYTES


@dataclass(frozen=True)
class PacketLayout:
    """How one sensor model fills a packet.

    column_us: duration of one firing column (every laser fired once; two VLP-16 firing
    sequences per block); blocks_per_column: blocks one column fills in single-return mode
    (HDL-64E: upper + lower block; VLS-128: four banks); distance_m: the packets' distance unit [m].
    """

    model: str
    n_lasers: int
    column_us: float
    blocks_per_column: int
    distance_m: float = 0.002

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
        if self.model == "VLP-32C":
            # VLP-32C manual, firing timing table (as the ROS velodyne driver, nebula and velodyne-decoder):
            # one block per 55.296 us firing sequence, the lasers fire in pairs 2.304 us apart
            column = block // (2 if dual else 1)
            return column * self.column_us + (channel // 2) * 2.304
        if self.model == "VLS-128":
            # VLS-128 (ROS velodyne driver and nebula, from the manual): four blocks (banks) per firing
            # sequence, 16 firing groups of 8 lasers 2.665 us apart with one group's time left idle
            # after group 8, the timestamp at the fourth group (8.7 us after the sequence starts)
            group = (32 * (block % 4) + channel) // 8
            return (block // 4) * self.column_us + (group + group // 8) * 2.665 - 8.7
        # HDL-64E S2 manual, laser firing time table (as in velodyne-decoder): upper and lower
        # block fire together every 48 us, four lasers at 0/1.26/2.46/3.66 us every 6 us
        column = block // (4 if dual else 2)
        pattern = np.array([0.0, 1.26, 2.46, 3.66])
        return column * 48.0 + (channel // 4) * 6.0 + pattern[channel % 4]

    def azimuth_read_us(self, dual: bool) -> np.ndarray:
        """(12, 1) when each block's azimuth was read, after the packet timestamp [us]: the first
        firing of its column (the VLS-128's four banks share their sequence's azimuth)."""
        timing = self.timing_us(dual)
        first = np.arange(12) - (np.arange(12) % 4 if self.model == "VLS-128" else 0)
        return timing[first, :1]

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
        if self.model in ("HDL-64E", "VLS-128"):
            bank = sum(b * (flags == flag) for b, flag in enumerate(BANK_FLAGS))
            return channel + 32 * bank[:, :, None]
        return np.broadcast_to(channel, flags.shape + (32,))


LAYOUTS = {
    "HDL-32E": PacketLayout("HDL-32E", 32, column_us=46.08, blocks_per_column=1),
    "VLP-16": PacketLayout("VLP-16", 16, column_us=2 * 55.296, blocks_per_column=1),
    "HDL-64E": PacketLayout("HDL-64E", 64, column_us=48.0, blocks_per_column=2),
    "VLP-32C": PacketLayout("VLP-32C", 32, column_us=55.296, blocks_per_column=1, distance_m=0.004),
    # 53.3 us per firing sequence in the drivers; a unit's own period depends on its firmware, and
    # the importer measures it from the packet rate (velodyne_pcap._layout)
    "VLS-128": PacketLayout("VLS-128", 128, column_us=53.3, blocks_per_column=4, distance_m=0.004),
}


class HourUnwrap:
    """Microseconds past the top of the hour -> microseconds past the first stamp's hour (float64), for the
    stamps of consecutive packets given chunk after chunk (a step back of more than half an hour is a new hour)."""

    def __init__(self):
        self._last_us: float | None = None
        self._hours = 0

    def __call__(self, stamp_us: np.ndarray) -> np.ndarray:
        stamp = np.asarray(stamp_us, dtype=np.float64)
        if not len(stamp):
            return stamp
        before = stamp[:1] if self._last_us is None else [self._last_us]
        hours = self._hours + np.cumsum(np.diff(np.concatenate([before, stamp])) < -1800e6)
        self._last_us, self._hours = float(stamp[-1]), int(hours[-1])
        return stamp + 3600e6 * hours


class RevolutionCounter:
    """(n, 12) revolution index of each block of consecutive packets given chunk after chunk: +1 each time the
    block azimuth decreases (wraps), from 0 at the first block."""

    def __init__(self):
        self._last: tuple[int, int] | None = None  # (block azimuth [0.01 deg], revolution) of the last block

    def __call__(self, packets: np.ndarray) -> np.ndarray:
        azimuth = packets["blocks"]["azimuth"].astype(np.int64).ravel()
        if not len(azimuth):
            return np.zeros((0, 12), dtype=np.int32)
        last_azimuth, last_scan = self._last or (int(azimuth[0]), 0)
        scan = last_scan + np.cumsum(np.diff(np.concatenate([[last_azimuth], azimuth])) < 0)
        self._last = (int(azimuth[-1]), int(scan[-1]))
        return scan.reshape(-1, 12).astype(np.int32)


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


def _column_steps(packets: np.ndarray, layout: PacketLayout, dual: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Azimuth steps between consecutive blocks (n, 11) [0.01 deg], the time between their azimuth
    readings (11,) [us], and which steps are field-of-view gaps (n, 11): a step more than twice the
    packet's smallest column step per us, where the head turned over an arc the sensor sent nothing
    for (a VLP-32C or VLS-128 set to a restricted field of view fills a packet across the gap)."""
    read = layout.azimuth_read_us(dual)[:, 0]
    dt = np.diff(read)
    step = np.mod(np.diff(packets["blocks"]["azimuth"].astype(np.float64), axis=1), 36000.0)
    per_us = np.where(dt > 0, step / np.where(dt > 0, dt, 1.0), np.inf)
    slack = 1.0 / dt.max()  # one encoder count over the longest column step, for a head at rest
    gap = (dt > 0) & (per_us > 2.0 * per_us.min(axis=1, keepdims=True) + slack)
    return step, dt, gap


def packet_rates(packets: np.ndarray, layout: PacketLayout, dual: bool) -> np.ndarray:
    """(n,) spin rate of each packet [0.01 deg / us]: its azimuth advance from the first to the
    last block over their firing times, leaving out field-of-view gaps (_column_steps)."""
    step, dt, gap = _column_steps(packets, layout, dual)
    return np.where(gap, 0.0, step).sum(axis=1) / np.where(gap, 0.0, dt).sum(axis=1)


def gap_us(packets: np.ndarray, layout: PacketLayout, dual: bool, rate: np.ndarray, time_us: np.ndarray,
           next_us: np.ndarray, next_azimuth: np.ndarray) -> np.ndarray:
    """(n, 12) time the head spent in field-of-view gaps before each block of its packet [us].

    The blocks after a gap are timed back from the next packet (timestamp next_us, first block
    azimuth next_azimuth; NaN when unknown) at the packet's rate: the gap's arc is too long for the
    rate of one packet (0.5 % off over a half turn is 0.25 ms). Without a next packet within a
    few columns, the gap's arc at that rate, less the column time the table gives it."""
    step, dt, gap = _column_steps(packets, layout, dual)
    safe_rate = np.where(rate > 0, rate, 1.0)[:, None]
    extra = np.where(gap & (rate[:, None] > 0), step / safe_rate - dt, 0.0)
    late = np.concatenate([np.zeros((len(step), 1)), np.cumsum(extra, axis=1)], axis=1)
    read = layout.azimuth_read_us(dual)[:, 0]
    azimuth = packets["blocks"]["azimuth"].astype(np.float64)
    to_next = np.mod(next_azimuth[:, None] - azimuth, 36000.0) / safe_rate  # NaN without a next packet
    after = np.cumsum(np.concatenate([np.zeros((len(step), 1)), gap], axis=1), axis=1) > 0
    close = to_next[:, -1] < 3.0 * (layout.packet_us(dual) / 12 * layout.blocks_per_column)
    from_next = next_us[:, None] - to_next - time_us[:, None] - read[None, :]
    return np.where(after & close[:, None], from_next, late)


def decode_returns(packets: np.ndarray, layout: PacketLayout, dual: bool, time_us: np.ndarray,
                   scan: np.ndarray, distance_m: float = 0.002, interpolate_azimuth: bool = True,
                   next_packet: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """Raw returns of packets (structured PACKET array), those `returned` keeps.

    time_us: (n,) packet timestamps, unwrapped past the hour; scan: (n, 12) revolution index;
    next_packet: (n,) timestamp and first block azimuth of each packet's successor (NaN for none).
    The rotation rate is each packet's mean: its azimuth advance from the first to the last block;
    a block after a field-of-view gap is stamped later by the time the head took to cross it (gap_us).
    Returns arrays in packet/block/channel order: time_s (float64, s past the hour), fibre,
    range [m], azimuth [rad, encoder, clockwise, wrapped to [0, 2 pi)], intensity, scan.
    """
    blocks = packets["blocks"]
    table = layout.timing_us(dual)
    distance = blocks["returns"]["distance"]
    valid = returned(packets, layout, dual)
    block_azimuth = blocks["azimuth"].astype(np.float64)
    rate = packet_rates(packets, layout, dual)
    if next_packet is None:
        next_packet = (np.append(time_us[1:], np.nan), np.append(block_azimuth[1:, 0], np.nan))
    timing = table[None] + gap_us(packets, layout, dual, rate, time_us, *next_packet)[:, :, None]
    after_block_us = (table - layout.azimuth_read_us(dual)) if interpolate_azimuth else layout.sequence_start_us()[None, :]
    azimuth = block_azimuth[:, :, None] + rate[:, None, None] * after_block_us[None]
    return {
        "time_s": (time_us[:, None, None] + timing)[valid] * 1e-6,
        "fibre": layout.laser_ids(blocks["flag"])[valid].astype(np.int16),
        "range": (distance[valid] * distance_m).astype(np.float32),
        "azimuth": np.radians(np.mod(azimuth[valid], 36000.0) / 100.0).astype(np.float32),
        "intensity": blocks["returns"]["intensity"][valid].astype(np.float32),
        "scan": np.broadcast_to(scan[:, :, None], distance.shape)[valid],
    }
