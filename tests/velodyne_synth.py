"""Small synthetic Velodyne captures for the importer tests: packets built byte by byte with
struct (independently of graphcal's parser), wrapped in Ethernet/IPv4/UDP and a libpcap file."""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

PCAP_HEADER = struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1)


def udp_frame(payload: bytes, port: int) -> bytes:
    ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 28 + len(payload), 0, 0x4000, 64, 17, 0,
                     bytes([192, 168, 1, 201]), bytes([255, 255, 255, 255]))
    return b"\xff" * 6 + b"\x60\x76\x88\x00\x00\x00" + b"\x08\x00" + ip + struct.pack(">HHHH", 2368, port,
                                                                                       8 + len(payload), 0) + payload


def pcap_file(records: list[tuple[float, bytes]], captured: int | None = None) -> bytes:
    """records: (capture time s since 1970, link-layer frame); captured cuts each frame to that many bytes."""
    out = [PCAP_HEADER]
    for time_s, frame in records:
        kept = frame[:captured] if captured else frame
        out.append(struct.pack("<IIII", int(time_s), round((time_s % 1) * 1e6), len(kept), len(frame)) + kept)
    return b"".join(out)


def data_packet(azimuth: np.ndarray, distance: np.ndarray, intensity: np.ndarray, stamp_us: int,
                flags=None, mode: int = 0x37, product: int = 0x21) -> bytes:
    """azimuth (12,) in 0.01 deg, distance/intensity (12, 32), stamp in us past the hour."""
    flags = [0xEEFF] * 12 if flags is None else flags
    blocks = b"".join(struct.pack("<HH", flags[b], int(azimuth[b])) +
                      b"".join(struct.pack("<HB", int(d), int(i)) for d, i in zip(distance[b], intensity[b]))
                      for b in range(12))
    return blocks + struct.pack("<IBB", stamp_us, mode, product)


def position_packet(stamp_us: int, sentence: str) -> bytes:
    body = sentence[1:]
    checksum = 0
    for char in body.encode():
        checksum ^= char
    nmea = f"{sentence}*{checksum:02X}\r\n".encode()
    payload = bytearray(512)
    payload[198:202] = struct.pack("<I", stamp_us)
    payload[206:206 + len(nmea)] = nmea
    return bytes(payload)


@dataclass
class Capture:
    """A synthetic capture and the ground truth written into it."""

    pcap: bytes
    azimuth: np.ndarray     # (packets, 12) block azimuth, 0.01 deg
    distance: np.ndarray    # (packets, 12, 32) raw distance, 2 mm units
    intensity: np.ndarray
    stamp_us: np.ndarray    # (packets,) us past the hour


def spinning_capture(n_packets: int, packet_us: float, block_step: float, seed: int = 0, start_azimuth: float = 34000.0,
                     start_us: int = 1_000_000, pair_blocks: int = 1, flags=None, mode: int = 0x37, product: int = 0x21,
                     host_start_s: float = 1614853000.0, extra=()) -> Capture:
    """A head spinning at a constant rate: `pair_blocks` consecutive blocks share one azimuth
    (HDL-64E upper/lower, dual return), the azimuth advances by block_step per firing column.
    About 10 % of the returns are zero ("no return")."""
    rng = np.random.default_rng(seed)
    columns = np.arange(12) // pair_blocks
    azimuth = np.zeros((n_packets, 12), dtype=np.int64)
    stamps = (start_us + np.round(np.arange(n_packets) * packet_us)).astype(np.int64)
    for p in range(n_packets):
        column_index = p * (12 // pair_blocks) + columns
        azimuth[p] = np.round(start_azimuth + block_step * column_index).astype(np.int64) % 36000
    distance = rng.integers(250, 65_000, size=(n_packets, 12, 32))  # 0.5 .. 130 m
    distance[rng.random(distance.shape) < 0.1] = 0
    intensity = rng.integers(0, 256, size=(n_packets, 12, 32))
    records = [(host_start_s + stamps[p] * 1e-6, udp_frame(
        data_packet(azimuth[p], distance[p], intensity[p], int(stamps[p]), flags, mode, product), 2368))
        for p in range(n_packets)]
    records += list(extra)
    records.sort(key=lambda record: record[0])
    return Capture(pcap_file(records), azimuth, distance, intensity, stamps)
