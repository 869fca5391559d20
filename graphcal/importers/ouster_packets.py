"""Ouster lidar UDP packets -> per-pixel arrays (NumPy, no I/O).

Layouts of the Ouster packet formats (sensor docs "Lidar Data Format"; ouster-sdk
ouster_core/src/parsing.cpp, `PacketFormat`), little-endian throughout:

- LEGACY: no packet header; per column a 16-byte header (timestamp u64 ns, measurement_id u16,
  frame_id u16 (read from the first column, as ouster-sdk does), encoder count u32), 12 bytes per pixel (range: bits 0-19 of a u32, mm;
  reflectivity: byte 4), a u32 status after the pixels (bit 0: valid).
- RNG19_RFL8_SIG16_NIR16: 32-byte packet header (packet type u16, frame_id u16, ...), per column
  a 12-byte header (timestamp u64 ns, measurement_id u16, status u16, bit 0: valid), 12 bytes per
  pixel (range: bits 0-18 of a u32, mm; reflectivity: byte 4), a 32-byte packet footer.
- RNG15_RFL8_NIR8 (low data rate): as above with 4 bytes per pixel (range: bits 0-14 of a u16,
  in units of 8 mm; reflectivity: byte 2).

A range of 0 is no return.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PixelLayout:
    """Where a profile keeps what graphcal reads. Sizes in bytes."""

    packet_header: int
    column_header: int
    pixel: int
    column_footer: int
    packet_footer: int
    range_bits: int
    range_unit_mm: int
    reflectivity_at: int

    def column_bytes(self, pixels: int) -> int:
        return self.column_header + pixels * self.pixel + self.column_footer

    def packet_bytes(self, columns: int, pixels: int) -> int:
        return self.packet_header + columns * self.column_bytes(pixels) + self.packet_footer


LAYOUTS = {
    "LEGACY": PixelLayout(0, 16, 12, 4, 0, range_bits=20, range_unit_mm=1, reflectivity_at=4),
    "RNG19_RFL8_SIG16_NIR16": PixelLayout(32, 12, 12, 0, 32, range_bits=19, range_unit_mm=1, reflectivity_at=4),
    "RNG15_RFL8_NIR8": PixelLayout(32, 12, 4, 0, 32, range_bits=15, range_unit_mm=8, reflectivity_at=2),
}


@dataclass(frozen=True)
class ColumnData:
    """Decoded packets, one row per column (n_packets * columns_per_packet rows, packet order).

    timestamp_ns (u64, sensor clock), measurement_id (column index in the frame), frame_id
    (u16, wraps), valid (column status bit 0); range_mm (rows, pixels) and reflectivity (rows,
    pixels, 0-255); packet: each row's packet index.
    """

    timestamp_ns: np.ndarray
    measurement_id: np.ndarray
    frame_id: np.ndarray
    valid: np.ndarray
    range_mm: np.ndarray
    reflectivity: np.ndarray
    packet: np.ndarray


def decode_columns(packets: np.ndarray, profile: str, columns_per_packet: int, pixels: int) -> ColumnData:
    """(n, packet_bytes) uint8 lidar packets of `profile` -> ColumnData."""
    layout = LAYOUTS[profile]
    n = len(packets)
    column_bytes = layout.column_bytes(pixels)
    body = packets[:, layout.packet_header:layout.packet_header + columns_per_packet * column_bytes]
    columns = np.ascontiguousarray(body).reshape(n * columns_per_packet, column_bytes)
    timestamp = columns[:, 0:8].copy().view("<u8").ravel()
    measurement_id = columns[:, 8:10].copy().view("<u2").ravel()
    if layout.packet_header:
        status = columns[:, 10:12].copy().view("<u2").ravel().astype(np.uint32)
        frame_id = np.repeat(packets[:, 2:4].copy().view("<u2").ravel(), columns_per_packet)
    else:
        status = columns[:, column_bytes - 4:].copy().view("<u4").ravel()
        frame_id = np.repeat(packets[:, 10:12].copy().view("<u2").ravel(), columns_per_packet)  # first column's
    pixel_data = columns[:, layout.column_header:layout.column_header + pixels * layout.pixel]
    pixel_data = pixel_data.reshape(len(columns), pixels, layout.pixel)
    word_bytes = 4 if layout.range_bits > 16 else 2
    word = np.ascontiguousarray(pixel_data[..., :word_bytes]).view(f"<u{word_bytes}")[..., 0].astype(np.uint32)
    range_mm = (word & ((1 << layout.range_bits) - 1)) * np.uint32(layout.range_unit_mm)
    return ColumnData(timestamp_ns=timestamp, measurement_id=measurement_id, frame_id=frame_id,
                      valid=(status & 1) == 1, range_mm=range_mm,
                      reflectivity=pixel_data[..., layout.reflectivity_at].copy(),
                      packet=np.repeat(np.arange(n), columns_per_packet))
