"""Classic libpcap files: the UDP payloads they hold, with capture time and destination port.

Reads the global header (micro- or nanosecond timestamps, either byte order), walks the record
headers, and finds the UDP payload of each IPv4 record under an Ethernet (optionally VLAN
tagged), Linux cooked (SLL, SLL2) or raw-IP link layer. Records of any other kind (ARP, IPv6,
TCP, IP fragments) are counted and skipped. pcapng files are refused with a clear error.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
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
    """The UDP payloads of a capture, in file order.

    time_s: capture (host clock) time of each record, s since 1970 UTC; port: destination port;
    start/length: where each payload lies in `data`; record: its 0-based record index in the file;
    cut_bytes: the bytes of an incomplete last record dropped (what a crashed capture leaves), 0 for none.
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
    """Parse a libpcap file into its UDP payloads; RecordingError for a truncated or foreign file."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(path, "file not found")
    data = np.fromfile(path, dtype=np.uint8)
    head = data[:4].tobytes()
    if head == _PCAPNG:
        raise RecordingError(path, "pcapng file", expected="a classic libpcap file (convert it with "
                                                           "'editcap -F pcap IN OUT')")
    if len(data) < 24 or head not in _MAGIC:
        raise RecordingError(path, f"first bytes {head.hex()}", expected="a libpcap file (magic a1b2c3d4 or a1b23c4d)")
    order, tick = _MAGIC[head]
    link = struct.unpack_from(order + "I", data, 20)[0]
    if link not in _LINK_LAYERS:
        raise RecordingError(path, f"link type {link}", field="link type",
                             expected="Ethernet (1), Linux cooked (113, 276) or raw IP (12, 101, 228)")
    offsets, seconds, fractions, captured, cut_bytes = _walk_records(path, data, order)
    time_s = seconds + fractions * tick
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
                       length=np.minimum(udp_length, end[keep] - start), record=keep, n_records=n, cut_bytes=cut_bytes)


def _walk_records(path: Path, data: np.ndarray, order: str):
    """Offsets and header fields of every whole record, and the bytes of an incomplete last record (the file ends
    inside it: a capture cut short), which are dropped."""
    buffer, size = data.data, len(data)
    header = struct.Struct(order + "IIII")
    offsets, seconds, fractions, captured = [], [], [], []
    offset = 24
    while offset < size:
        if offset + 16 > size:
            break
        sec, frac, incl, _ = header.unpack_from(buffer, offset)
        if offset + 16 + incl > size:
            break
        offsets.append(offset)
        seconds.append(sec)
        fractions.append(frac)
        captured.append(incl)
        offset += 16 + incl
    return (np.asarray(offsets, dtype=np.int64), np.asarray(seconds, dtype=np.float64),
            np.asarray(fractions, dtype=np.float64), np.asarray(captured, dtype=np.int64), size - offset)


def _u16be(data: np.ndarray, at: np.ndarray, captured: np.ndarray, needed: int) -> np.ndarray:
    """Big-endian uint16 at byte positions `at` (-1 where the record is too short to hold it)."""
    value = np.full(len(at), -1, dtype=np.int64)
    ok = captured >= needed
    value[ok] = data[at[ok]].astype(np.int64) << 8 | data[at[ok] + 1]
    return value
