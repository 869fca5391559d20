"""Classic libpcap files: the UDP payloads they hold, with capture time and destination port.

Reads the global header (micro- or nanosecond timestamps, either byte order), walks the record
headers (the whole file at once, or a chunk of it at a time), and finds the UDP payload of each IPv4 record under an Ethernet (optionally VLAN
tagged), Linux cooked (SLL, SLL2) or raw-IP link layer. Records of any other kind (ARP, IPv6,
TCP, IP fragments) are counted and skipped. pcapng files are refused with a clear error.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError

_MAGIC = {b"\xd4\xc3\xb2\xa1": ("<", 1e-6), b"\xa1\xb2\xc3\xd4": (">", 1e-6),
          b"\x4d\x3c\xb2\xa1": ("<", 1e-9), b"\xa1\xb2\x3c\x4d": (">", 1e-9)}
_PCAPNG = b"\x0a\x0d\x0d\x0a"
# link type -> (bytes before the network header, offset of the 2-byte protocol field or None for raw IP)
_LINK_LAYERS = {1: (14, 12), 113: (16, 14), 276: (20, 0), 101: (0, None), 12: (0, None), 228: (0, None)}
_IPV4, _VLAN, _UDP = 0x0800, 0x8100, 17


@dataclass(frozen=True)
class UdpPayloads:
    """The UDP payloads of a capture, or of a chunk of its records, in file order.

    time_s: capture (host clock) time of each record, s since 1970 UTC; port: destination port;
    start/length: where each payload lies in `data`; record: its 0-based record index in the file;
    n_records: the records of the chunk (of any kind); cut_bytes: the bytes of an incomplete last record
    dropped (what a crashed capture leaves), 0 for none and in every chunk but the last.
    """

    path: Path
    data: np.ndarray
    time_s: np.ndarray
    port: np.ndarray
    start: np.ndarray
    length: np.ndarray
    record: np.ndarray
    n_records: int
    cut_bytes: int = 0

    def stack(self, mask: np.ndarray, size: int) -> np.ndarray:
        """The selected payloads (all `size` bytes long) as one (n, size) uint8 array."""
        starts = self.start[mask]
        if not len(starts):
            return np.empty((0, size), dtype=np.uint8)
        view = memoryview(self.data)
        return np.frombuffer(b"".join(view[s:s + size] for s in starts.tolist()), dtype=np.uint8).reshape(-1, size)


def read_udp_payloads(path: str | Path) -> UdpPayloads:
    """Parse a libpcap file into its UDP payloads, the whole file at once (udp_payload_chunks)."""
    return next(udp_payload_chunks(path))


def udp_payload_chunks(path: str | Path, chunk_bytes: int | None = None) -> Iterator[UdpPayloads]:
    """The UDP payloads of a libpcap file, read chunk_bytes of the file at a time (the whole file when None): one
    UdpPayloads per read that completes a record, holding its whole records (record indices count from the file's
    first record), the last one with the bytes of an incomplete last record; one empty UdpPayloads for a file
    without a record. RecordingError for a truncated or foreign file."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(path, "file not found")
    with path.open("rb") as file:
        order, tick, link = _global_header(path, file.read(24))
        records, rest, held = 0, b"", None
        while block := file.read(chunk_bytes or -1):
            data = np.frombuffer(rest + block, dtype=np.uint8)
            offsets, seconds, fractions, captured, end = _walk_records(data, order)
            rest = data[end:].tobytes()
            if len(offsets):
                if held is not None:
                    yield held
                held = _payloads(path, data, link, offsets, seconds + fractions * tick, captured, records)
                records += len(offsets)
        if held is None:
            empty = np.zeros(0, dtype=np.int64)
            held = _payloads(path, np.zeros(0, dtype=np.uint8), link, empty, empty.astype(np.float64), empty, 0)
        yield replace(held, cut_bytes=len(rest))


def chunk_count(path: Path, chunk_bytes: int | None) -> int:
    """How many chunks udp_payload_chunks reads the file in, at most (a progress bar's length)."""
    return max(1, math.ceil(path.stat().st_size / chunk_bytes)) if chunk_bytes else 1


def _global_header(path: Path, head: bytes) -> tuple[str, float, int]:
    """(struct byte order, timestamp tick [s], link type) of a libpcap global header."""
    if head[:4] == _PCAPNG:
        raise RecordingError(path, "pcapng file", expected="a classic libpcap file (convert it with "
                                                           "'editcap -F pcap IN OUT')")
    if len(head) < 24 or head[:4] not in _MAGIC:
        raise RecordingError(path, f"first bytes {head[:4].hex()}" if head else "empty file",
                             expected="a libpcap file (magic a1b2c3d4 or a1b23c4d)")
    order, tick = _MAGIC[head[:4]]
    link = struct.unpack_from(order + "I", head, 20)[0]
    if link not in _LINK_LAYERS:
        raise RecordingError(path, f"link type {link}", field="link type",
                             expected="Ethernet (1), Linux cooked (113, 276) or raw IP (12, 101, 228)")
    return order, tick, link


def _payloads(path: Path, data: np.ndarray, link: int, offsets: np.ndarray, time_s: np.ndarray,
              captured: np.ndarray, first_record: int) -> UdpPayloads:
    """The UDP payloads of the records at `offsets` of `data` (record headers there, first_record its first)."""
    l2, proto_at = _LINK_LAYERS[link]
    n = len(offsets)
    network = offsets + 16 + l2
    if proto_at is None:
        proto = np.full(n, _IPV4)
    else:
        proto = _u16be(data, offsets + 16 + proto_at, captured, proto_at + 2)
        vlan = proto == _VLAN
        proto[vlan] = _u16be(data, offsets[vlan] + 16 + proto_at + 4, captured[vlan], proto_at + 6)
        network[vlan] += 4
    end = offsets + 16 + captured
    ok = (proto == _IPV4) & (network + 28 <= end)
    ip = network[ok]
    version_ihl = data[ip]
    flags_fragment = (data[ip + 6].astype(np.int64) << 8 | data[ip + 7]) & 0x3FFF  # more-fragments bit + offset
    is_udp = (version_ihl >> 4 == 4) & (data[ip + 9] == _UDP) & (flags_fragment == 0)
    keep = np.flatnonzero(ok)[is_udp]
    udp = ip[is_udp] + (version_ihl[is_udp] & 0x0F).astype(np.int64) * 4
    port = data[udp + 2].astype(np.int64) << 8 | data[udp + 3]
    udp_length = (data[udp + 4].astype(np.int64) << 8 | data[udp + 5]) - 8
    start = udp + 8
    return UdpPayloads(path=path, data=data, time_s=time_s[keep], port=port, start=start,
                       length=np.minimum(udp_length, end[keep] - start), record=first_record + keep, n_records=n)


def _walk_records(data: np.ndarray, order: str):
    """Offsets and header fields of the whole records of `data` (records from its first byte on), and where the
    first incomplete one starts (len(data) when none)."""
    buffer, size = data.data, len(data)
    header = struct.Struct(order + "IIII")
    offsets, seconds, fractions, captured = [], [], [], []
    offset = 0
    while offset + 16 <= size:
        sec, frac, incl, _ = header.unpack_from(buffer, offset)
        if offset + 16 + incl > size:
            break
        offsets.append(offset)
        seconds.append(sec)
        fractions.append(frac)
        captured.append(incl)
        offset += 16 + incl
    return (np.asarray(offsets, dtype=np.int64), np.asarray(seconds, dtype=np.float64),
            np.asarray(fractions, dtype=np.float64), np.asarray(captured, dtype=np.int64), offset)


def _u16be(data: np.ndarray, at: np.ndarray, captured: np.ndarray, needed: int) -> np.ndarray:
    """Big-endian uint16 at byte positions `at` (-1 where the record is too short to hold it)."""
    value = np.full(len(at), -1, dtype=np.int64)
    ok = captured >= needed
    value[ok] = data[at[ok]].astype(np.int64) << 8 | data[at[ok] + 1]
    return value
