"""PCD files (Point Cloud Library, v0.7 and older) -> a numpy structured array with every field.

Reads the header (FIELDS, SIZE, TYPE, COUNT, WIDTH, HEIGHT, POINTS, DATA) and the three data
encodings: `ascii` (one point per line), `binary` (packed records, point after point) and
`binary_compressed` (two little-endian uint32, compressed then raw size, then an LZF block that
holds the fields one after the other: all x, then all y, ...). Every field is kept, padding
(`_`) included, so ring and per-point time come through (open3d's reader drops them).
Binary data is little-endian, as PCL writes it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from graphcal.common.errors import RecordingError

_KINDS = {"F": "f", "U": "u", "I": "i"}
_ENCODINGS = ("ascii", "binary", "binary_compressed")
_HEADER_LINES = 64  # far more than a PCD header has


@dataclass(frozen=True)
class PcdHeader:
    """A PCD header: field names, their numpy dtypes (with COUNT > 1 as sub-arrays), point count, encoding."""

    fields: tuple[str, ...]
    dtype: np.dtype
    points: int
    encoding: str
    width: int
    height: int


def read_pcd(path: str | Path) -> tuple[PcdHeader, np.ndarray]:
    """(header, points as a structured array with one column per field) of a PCD file; RecordingError naming
    the header line or the size mismatch of a damaged file."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(path, "file not found")
    raw = path.read_bytes()
    header, start = _parse_header(path, raw)
    body = memoryview(raw)[start:]
    if header.encoding == "ascii":
        return header, _ascii(path, header, bytes(body))
    if header.encoding == "binary":
        need = header.points * header.dtype.itemsize
        if len(body) < need:
            raise RecordingError(path, f"{len(body)} data bytes", field="DATA",
                                 expected=f"{need} ({header.points} points of {header.dtype.itemsize} bytes)")
        return header, np.frombuffer(body[:need], dtype=header.dtype).copy()
    return header, _compressed(path, header, body)


def _parse_header(path: Path, raw: bytes) -> tuple[PcdHeader, int]:
    values, at = {}, 0
    for number in range(1, _HEADER_LINES + 1):
        end = raw.find(b"\n", at)
        if end < 0:
            break
        line = raw[at:end].decode("ascii", errors="replace").strip()
        at = end + 1
        if not line or line.startswith("#"):
            continue
        key, _, rest = line.partition(" ")
        values[key.upper()] = (rest.split(), number)
        if key.upper() == "DATA":
            return _header(path, values), at
    raise RecordingError(path, "no DATA line in the header", field="DATA",
                         expected="a PCD header ending with DATA ascii|binary|binary_compressed")


def _header(path: Path, values: dict) -> PcdHeader:
    def line(key: str) -> list[str]:
        if key not in values:
            raise RecordingError(path, "missing header line", field=key, expected="a PCD v0.7 header")
        return values[key][0]

    def integers(key: str) -> list[int]:
        try:
            return [int(v) for v in line(key)]
        except ValueError:
            raise RecordingError(path, f"{key} {' '.join(line(key))}", field=key, row=values[key][1],
                                 expected="integers") from None

    names = line("FIELDS")
    sizes = integers("SIZE")
    kinds = line("TYPE")
    counts = integers("COUNT") if "COUNT" in values else [1] * len(names)
    if not (len(names) == len(sizes) == len(kinds) == len(counts)):
        raise RecordingError(path, f"{len(names)} FIELDS, {len(sizes)} SIZE, {len(kinds)} TYPE, {len(counts)} COUNT",
                             field="FIELDS", expected="one SIZE, TYPE and COUNT per field")
    columns = []
    for index, (name, size, kind, count) in enumerate(zip(names, sizes, kinds, counts)):
        if kind.upper() not in _KINDS or size not in ((4, 8) if kind.upper() == "F" else (1, 2, 4, 8)) or count < 1:
            raise RecordingError(path, f"field {name!r}: TYPE {kind} SIZE {size} COUNT {count}", field="TYPE",
                                 row=index, expected="F (4 or 8 bytes), U or I (1, 2, 4 or 8 bytes), COUNT >= 1")
        unique = name if name not in [c[0] for c in columns] else f"{name}_{index}"  # PCL pads with several "_"
        columns.append((unique, f"<{_KINDS[kind.upper()]}{size}") + (((count,),) if count > 1 else ()))
    width, height = (integers(key)[0] for key in ("WIDTH", "HEIGHT"))
    points = integers("POINTS")[0] if "POINTS" in values else width * height
    encoding = line("DATA")[0].lower() if line("DATA") else ""
    if encoding not in _ENCODINGS:
        raise RecordingError(path, f"DATA {encoding!r}", field="DATA", expected=" or ".join(_ENCODINGS))
    return PcdHeader(tuple(c[0] for c in columns), np.dtype(columns), points, encoding, width, height)


def _ascii(path: Path, header: PcdHeader, body: bytes) -> np.ndarray:
    flat = [(name, header.dtype[name].base, int(np.prod(header.dtype[name].shape or (1,))))
            for name in header.fields]
    width = sum(count for _, _, count in flat)
    try:
        table = np.loadtxt(body.decode("ascii").splitlines(), dtype=np.float64, ndmin=2) if header.points else \
            np.zeros((0, width))
    except ValueError as error:
        raise RecordingError(path, f"ascii data: {error}", field="DATA", expected=f"{width} numbers per line") from None
    if table.shape != (header.points, width):
        raise RecordingError(path, f"{table.shape[0]} lines of {table.shape[1]} numbers", field="DATA",
                             expected=f"{header.points} lines of {width} numbers")
    points, column = np.zeros(header.points, dtype=header.dtype), 0
    for name, _, count in flat:
        values = table[:, column:column + count]
        points[name] = values[:, 0] if count == 1 else values
        column += count
    return points


def _compressed(path: Path, header: PcdHeader, body: memoryview) -> np.ndarray:
    import pylzf

    if len(body) < 8:
        raise RecordingError(path, "no compressed block", field="DATA", expected="two uint32 sizes and LZF data")
    compressed, size = (int(v) for v in np.frombuffer(body[:8], dtype="<u4"))
    need = header.points * header.dtype.itemsize
    if size != need or len(body) < 8 + compressed:
        raise RecordingError(path, f"compressed block of {compressed} bytes ({len(body) - 8} present) holding {size}",
                             field="DATA", expected=f"{need} bytes once decompressed ({header.points} points of "
                                                    f"{header.dtype.itemsize} bytes)")
    try:
        data = pylzf.decompress(bytes(body[8:8 + compressed]), size) if size else b""
    except ValueError:  # liblzf's error: the block is corrupt
        data = None
    if data is None or len(data) != size:
        raise RecordingError(path, "LZF block does not decompress", field="DATA", expected=f"{size} bytes")
    points, at = np.zeros(header.points, dtype=header.dtype), 0
    for name in header.fields:
        column = header.dtype[name]
        length = header.points * column.itemsize
        points[name] = np.frombuffer(data[at:at + length], dtype=column.base).reshape((header.points,) + column.shape)
        at += length
    return points
