"""Pure-Python structural validation of an OpenEXR file, run before the native library sees it.

Native EXR decoders have a long history of crashes, hangs and huge allocations on damaged files (the
OpenEXR project keeps ~185 fuzzer-found files in `openexr-images/Damaged/`). A crash inside a native
library cannot be caught, so `validate_exr` re-checks what the library would trust:

- magic number, version and flag bits;
- every attribute of every header, with bounds checks, fixed sizes for known types, and a full parse
  of `channels`, `tiles`, `preview` and string vectors;
- required attributes, data/display windows (size limits below), compression, line order, tiles;
- chunk count (recomputed like OpenEXRCore does, including mip/rip-map levels);
- the offset table: every chunk must lie inside the file and start with the chunk header the table
  position implies (part number, scan line or tile coordinates and level), with a sane byte count.

Deep (non-image) data, subsampled channels and the newer ZSTD / LJ2K codecs (whose chunk layout
differs between OpenEXR releases) are refused as unsupported. The layout follows the
"OpenEXR File Layout" document and OpenEXRCore (`validation.c`, `parse_header.c`).
"""

import math
import mmap
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    "MAX_CHANNELS",
    "MAX_DECODED_BYTES",
    "MAX_PIXELS",
    "MAX_SIDE",
    "MAX_TILE_PIXELS",
    "ExrChannelInfo",
    "ExrCorruptError",
    "ExrFileInfo",
    "ExrPartInfo",
    "tile_levels",
    "validate_exr",
    "validate_exr_bytes",
]

MAGIC = 20000630
MAX_SIDE = 1 << 16
"""Largest data-window width or height accepted (65536)."""
MAX_PIXELS = 1 << 28
"""Largest data-window area accepted per part (268M pixels, e.g. 16384 x 16384)."""
MAX_TILE_PIXELS = 1 << 24
"""Largest tile area accepted (16M pixels, e.g. 4096 x 4096)."""
MAX_DECODED_BYTES = 1 << 32
"""Largest total decoded size (all parts, all channels, base level) accepted: 4 GiB."""
MAX_CHANNELS = 1024
MAX_PARTS = 1024

_VERSION_MASK = 0xFF
_TILED_FLAG = 0x200
_LONG_NAMES_FLAG = 0x400
_NON_IMAGE_FLAG = 0x800
_MULTI_PART_FLAG = 0x1000
_VALID_FLAGS = _TILED_FLAG | _LONG_NAMES_FLAG | _NON_IMAGE_FLAG | _MULTI_PART_FLAG
_LARGE_COORD = (2**31 - 1) // 2  # OpenEXRCore `kLargeVal`

# Scan lines per chunk for each compression id (OpenEXRCore `exr_compression_lines_per_chunk`).
LINES_PER_CHUNK = {
    0: 1,
    1: 1,
    2: 1,
    3: 16,
    4: 32,
    5: 16,
    6: 32,
    7: 32,
    8: 32,
    9: 256,
    10: 256,
    11: 32,
}
COMPRESSION_NAMES = {
    0: "none",
    1: "rle",
    2: "zips",
    3: "zip",
    4: "piz",
    5: "pxr24",
    6: "b44",
    7: "b44a",
    8: "dwaa",
    9: "dwab",
    10: "htj2k256",
    11: "htj2k32",
}
# Newer codecs whose chunk layout differs between OpenEXR releases (3.5.3 writes ZSTD with one scan
# line per chunk, third-party readers assume 32): refused rather than guessed.
_UNSUPPORTED_COMPRESSION = {12: "lj2k", 13: "zstd"}
PIXEL_TYPE_BYTES = {0: 4, 1: 2, 2: 4}  # UINT, HALF, FLOAT
PIXEL_TYPE_NAMES = {0: "uint", 1: "half", 2: "float"}
STORAGE_TYPES = ("scanlineimage", "tiledimage", "deepscanline", "deeptile")

_FIXED_SIZE = {
    "box2i": 16,
    "box2f": 16,
    "chromaticities": 32,
    "compression": 1,
    "deepImageState": 1,
    "double": 8,
    "envmap": 1,
    "float": 4,
    "int": 4,
    "keycode": 28,
    "lineOrder": 1,
    "m33f": 36,
    "m33d": 72,
    "m44f": 64,
    "m44d": 128,
    "rational": 8,
    "tiledesc": 9,
    "timecode": 8,
    "v2i": 8,
    "v2f": 8,
    "v2d": 16,
    "v3i": 12,
    "v3f": 12,
    "v3d": 24,
}
_REQUIRED_TYPES = {
    "channels": "chlist",
    "compression": "compression",
    "dataWindow": "box2i",
    "displayWindow": "box2i",
    "lineOrder": "lineOrder",
    "pixelAspectRatio": "float",
    "screenWindowCenter": "v2f",
    "screenWindowWidth": "float",
}
_OPTIONAL_TYPES = {
    "tiles": "tiledesc",
    "name": "string",
    "type": "string",
    "chunkCount": "int",
    "version": "int",
    "envmap": "envmap",
}


class ExrCorruptError(ValueError):
    """The bytes are not a valid (or not a supported) OpenEXR file; the message says why."""

    def __init__(self, reason: str, *, unsupported: bool = False) -> None:
        super().__init__(reason)
        self.reason = reason
        self.unsupported = unsupported


@dataclass(frozen=True)
class ExrChannelInfo:
    """One entry of a `chlist` attribute."""

    name: str
    pixel_type: int
    x_sampling: int
    y_sampling: int

    @property
    def nbytes(self) -> int:
        """Bytes per sample."""
        return PIXEL_TYPE_BYTES[self.pixel_type]


@dataclass(frozen=True)
class ExrTiles:
    """A `tiledesc` attribute: tile size, level mode (0 one, 1 mip, 2 rip), rounding (0 down, 1 up)."""

    x_size: int
    y_size: int
    level_mode: int
    rounding: int


@dataclass(frozen=True)
class ExrPartInfo:
    """What `validate_exr` learnt about one part (header) of the file."""

    index: int
    name: str | None
    storage: str
    channels: tuple[ExrChannelInfo, ...]
    compression: int
    data_window: tuple[int, int, int, int]
    display_window: tuple[int, int, int, int]
    line_order: int
    tiles: ExrTiles | None
    envmap: int | None
    chunk_count: int
    attribute_types: dict[str, str] = field(default_factory=dict, compare=False)

    @property
    def width(self) -> int:
        """Data-window width."""
        return self.data_window[2] - self.data_window[0] + 1

    @property
    def height(self) -> int:
        """Data-window height."""
        return self.data_window[3] - self.data_window[1] + 1


@dataclass(frozen=True)
class ExrFileInfo:
    """Result of `validate_exr`: the parts, in file order."""

    version: int
    multipart: bool
    parts: tuple[ExrPartInfo, ...]
    file_size: int


class _Reader:
    """Bounds-checked little-endian reads from a buffer."""

    def __init__(self, buf: mmap.mmap | bytes, pos: int = 0, end: int | None = None) -> None:
        self.buf = buf
        self.pos = pos
        self.end = len(buf) if end is None else end

    def need(self, n: int, what: str) -> None:
        if n < 0 or self.pos + n > self.end:
            raise ExrCorruptError(
                f"truncated: {what} needs {n} byte(s) at offset {self.pos}, "
                f"only {max(self.end - self.pos, 0)} left"
            )

    def unpack(self, fmt: str, what: str) -> tuple:
        size = struct.calcsize(fmt)
        self.need(size, what)
        values = struct.unpack_from(fmt, self.buf, self.pos)
        self.pos += size
        return values

    def u8(self, what: str) -> int:
        return self.unpack("<B", what)[0]

    def i32(self, what: str) -> int:
        return self.unpack("<i", what)[0]

    def u32(self, what: str) -> int:
        return self.unpack("<I", what)[0]

    def cstr(self, max_len: int, what: str) -> str:
        """A NUL-terminated string of at most `max_len` bytes (not counting the NUL)."""
        limit = min(self.end, self.pos + max_len + 1)
        stop = self.buf.find(b"\0", self.pos, limit)
        if stop < 0:
            if limit == self.end:
                raise ExrCorruptError(f"truncated: {what} at offset {self.pos} has no terminator")
            raise ExrCorruptError(f"{what} at offset {self.pos} is longer than {max_len} bytes")
        raw = bytes(self.buf[self.pos : stop])
        self.pos = stop + 1
        return raw.decode("latin-1")


# ----------------------------------------------------------------------------------------------
# attribute values


def _parse_chlist(r: _Reader, max_len: int) -> tuple[ExrChannelInfo, ...]:
    channels: list[ExrChannelInfo] = []
    while True:
        name = r.cstr(max_len, "channel name")
        if not name:
            break
        pixel_type, _p_linear, x_sampling, y_sampling = r.unpack("<iB3xii", f"channel {name!r}")
        if pixel_type not in PIXEL_TYPE_BYTES:
            raise ExrCorruptError(f"channel {name!r} has invalid pixel type {pixel_type}")
        if x_sampling < 1 or y_sampling < 1:
            raise ExrCorruptError(
                f"channel {name!r} has invalid sampling ({x_sampling}, {y_sampling})"
            )
        channels.append(ExrChannelInfo(name, pixel_type, x_sampling, y_sampling))
        if len(channels) > MAX_CHANNELS:
            raise ExrCorruptError(f"more than {MAX_CHANNELS} channels")
    if r.pos != r.end:
        raise ExrCorruptError("channel list size does not match its declared attribute size")
    names = [c.name for c in channels]
    if len(set(names)) != len(names):
        raise ExrCorruptError(f"duplicate channel names in {names}")
    return tuple(channels)


def _parse_tiles(r: _Reader) -> ExrTiles:
    x_size, y_size, mode = r.unpack("<IIB", "tiles")
    level_mode, rounding = mode & 0x0F, mode >> 4
    if level_mode not in (0, 1, 2) or rounding not in (0, 1):
        raise ExrCorruptError(f"tiles attribute has invalid level/rounding mode byte {mode:#x}")
    if x_size < 1 or y_size < 1 or x_size > MAX_SIDE or y_size > MAX_SIDE:
        raise ExrCorruptError(f"invalid tile size {x_size} x {y_size}")
    if x_size * y_size > MAX_TILE_PIXELS:
        raise ExrCorruptError(
            f"tile size {x_size} x {y_size} exceeds the supported {MAX_TILE_PIXELS} pixels"
        )
    return ExrTiles(x_size, y_size, level_mode, rounding)


def _check_string_vector(r: _Reader) -> None:
    while r.pos < r.end:
        length = r.i32("string vector entry length")
        if length < 0:
            raise ExrCorruptError(f"negative string length {length} in a string vector")
        r.need(length, "string vector entry")
        r.pos += length


def _check_preview(r: _Reader) -> None:
    width, height = r.unpack("<II", "preview size")
    if 4 * width * height != r.end - r.pos:
        raise ExrCorruptError(f"preview image {width} x {height} does not match its byte count")


def _check_value(type_name: str, value: _Reader, attr: str) -> None:
    size = value.end - value.pos
    expected = _FIXED_SIZE.get(type_name)
    if expected is not None and size != expected:
        raise ExrCorruptError(
            f"attribute {attr!r} of type {type_name!r} has size {size}, expected {expected}"
        )
    if type_name == "stringvector":
        _check_string_vector(value)
    elif type_name == "preview":
        _check_preview(value)
    elif type_name == "floatvector" and size % 4:
        raise ExrCorruptError(
            f"attribute {attr!r} (floatvector) has size {size}, not a multiple of 4"
        )


# ----------------------------------------------------------------------------------------------
# headers


@dataclass
class _RawHeader:
    attrs: dict[str, tuple[str, int, int]]  # name -> (type, value offset, value size)


def _read_header(r: _Reader, max_len: int) -> _RawHeader:
    attrs: dict[str, tuple[str, int, int]] = {}
    while True:
        name = r.cstr(max_len, "attribute name")
        if not name:
            return _RawHeader(attrs)
        type_name = r.cstr(max_len, f"type name of attribute {name!r}")
        if not type_name:
            raise ExrCorruptError(f"attribute {name!r} has an empty type name")
        size = r.i32(f"size of attribute {name!r}")
        r.need(size, f"value of attribute {name!r}")
        if name in attrs:
            raise ExrCorruptError(f"attribute {name!r} appears twice in one header")
        _check_value(type_name, _Reader(r.buf, r.pos, r.pos + size), name)
        attrs[name] = (type_name, r.pos, size)
        r.pos += size


def _attr_reader(buf: mmap.mmap | bytes, header: _RawHeader, name: str) -> _Reader:
    _type, offset, size = header.attrs[name]
    return _Reader(buf, offset, offset + size)


def _check_types(header: _RawHeader, index: int) -> None:
    for name in _REQUIRED_TYPES:
        if name not in header.attrs:
            raise ExrCorruptError(f"part {index}: required attribute {name!r} is missing")
    for name, type_name in {**_REQUIRED_TYPES, **_OPTIONAL_TYPES}.items():
        if name in header.attrs and header.attrs[name][0] != type_name:
            raise ExrCorruptError(
                f"part {index}: attribute {name!r} has type {header.attrs[name][0]!r}, "
                f"expected {type_name!r}"
            )


def _box(buf: mmap.mmap | bytes, header: _RawHeader, name: str) -> tuple[int, int, int, int]:
    x0, y0, x1, y1 = _attr_reader(buf, header, name).unpack("<iiii", name)
    if x0 > x1 or y0 > y1:
        raise ExrCorruptError(f"{name} ({x0}, {y0}) - ({x1}, {y1}) is empty or inverted")
    if min(x0, y0) <= -_LARGE_COORD or max(x1, y1) >= _LARGE_COORD:
        raise ExrCorruptError(f"{name} ({x0}, {y0}) - ({x1}, {y1}) has out-of-range coordinates")
    return x0, y0, x1, y1


def _check_data_window(dw: tuple[int, int, int, int]) -> None:
    width, height = dw[2] - dw[0] + 1, dw[3] - dw[1] + 1
    if width > MAX_SIDE or height > MAX_SIDE or width * height > MAX_PIXELS:
        raise ExrCorruptError(
            f"image size {width} x {height} exceeds the supported limits "
            f"({MAX_SIDE} per side, {MAX_PIXELS} pixels)",
            unsupported=True,
        )


def _storage(header: _RawHeader, buf: mmap.mmap | bytes, flags: int, multipart: bool) -> str:
    if "type" in header.attrs:
        r = _attr_reader(buf, header, "type")
        type_str = bytes(buf[r.pos : r.end]).decode("latin-1")
        if type_str not in STORAGE_TYPES:
            raise ExrCorruptError(f"unknown part type {type_str!r}")
        if not multipart and flags & _TILED_FLAG:
            return "tiledimage"  # OpenEXR believes the flag over the type string
        return type_str
    if multipart or flags & _NON_IMAGE_FLAG:
        raise ExrCorruptError("attribute 'type' is required in multi-part and deep files")
    return "tiledimage" if flags & _TILED_FLAG else "scanlineimage"


def _level_sizes(size: int, levels: int, rounding: int) -> list[int]:
    out = []
    for level in range(levels):
        s = size >> level
        if rounding == 1 and (s << level) < size:
            s += 1
        out.append(max(s, 1))
    return out


def _num_levels(size: int, rounding: int) -> int:
    # floor(log2(size)) + 1, or ceil(log2(size)) + 1 when rounding up
    floor_log2 = size.bit_length() - 1
    if rounding == 1 and (1 << floor_log2) < size:
        return floor_log2 + 2
    return floor_log2 + 1


def tile_levels(w: int, h: int, tiles: ExrTiles) -> list[tuple[int, int, int, int]]:
    """`(level_x, level_y, level_width, level_height)` in offset-table order for a `w` x `h` part.

    Mip-map levels are listed in order; rip-map levels with `level_y` outer, `level_x` inner
    (OpenEXR `TileOffsets`).
    """
    if tiles.level_mode == 0:
        return [(0, 0, w, h)]
    if tiles.level_mode == 1:
        n = _num_levels(max(w, h), tiles.rounding)
        ws, hs = _level_sizes(w, n, tiles.rounding), _level_sizes(h, n, tiles.rounding)
        return [(lv, lv, ws[lv], hs[lv]) for lv in range(n)]
    nx, ny = _num_levels(w, tiles.rounding), _num_levels(h, tiles.rounding)
    ws, hs = _level_sizes(w, nx, tiles.rounding), _level_sizes(h, ny, tiles.rounding)
    return [(lx, ly, ws[lx], hs[ly]) for ly in range(ny) for lx in range(nx)]


def _chunk_count(
    storage: str, compression: int, dw: tuple[int, int, int, int], tiles: ExrTiles | None
) -> int:
    height = dw[3] - dw[1] + 1
    if storage == "scanlineimage":
        lines = LINES_PER_CHUNK[compression]
        return -(-height // lines)
    if tiles is None:
        raise ExrCorruptError("tiled part without a 'tiles' attribute")
    levels = tile_levels(dw[2] - dw[0] + 1, height, tiles)
    return sum(-(-lw // tiles.x_size) * -(-lh // tiles.y_size) for _lx, _ly, lw, lh in levels)


def _part_info(
    buf: mmap.mmap | bytes,
    header: _RawHeader,
    index: int,
    flags: int,
    multipart: bool,
    max_len: int,
) -> ExrPartInfo:
    _check_types(header, index)
    storage = _storage(header, buf, flags, multipart)
    if storage.startswith("deep"):
        raise ExrCorruptError(f"part {index} holds deep data ({storage})", unsupported=True)
    channels = _parse_chlist(_attr_reader(buf, header, "channels"), max_len)
    if not channels:
        raise ExrCorruptError(f"part {index} has no channels")
    subsampled = [c.name for c in channels if (c.x_sampling, c.y_sampling) != (1, 1)]
    if subsampled:
        raise ExrCorruptError(
            f"part {index} has subsampled channels {subsampled} (e.g. luminance/chroma)",
            unsupported=True,
        )
    compression = _attr_reader(buf, header, "compression").u8("compression")
    if compression in _UNSUPPORTED_COMPRESSION:
        raise ExrCorruptError(
            f"part {index} uses {_UNSUPPORTED_COMPRESSION[compression]} compression",
            unsupported=True,
        )
    if compression not in LINES_PER_CHUNK:
        raise ExrCorruptError(f"part {index} has unknown compression id {compression}")
    data_window = _box(buf, header, "dataWindow")
    display_window = _box(buf, header, "displayWindow")
    _check_data_window(data_window)
    line_order = _attr_reader(buf, header, "lineOrder").u8("lineOrder")
    if line_order not in (0, 1, 2):
        raise ExrCorruptError(f"part {index} has invalid line order {line_order}")
    (aspect,) = _attr_reader(buf, header, "pixelAspectRatio").unpack("<f", "pixelAspectRatio")
    if not (math.isfinite(aspect) and 1e-6 <= aspect <= 1e6):
        raise ExrCorruptError(f"part {index} has invalid pixel aspect ratio {aspect}")
    tiles = None
    if storage == "tiledimage":
        if "tiles" not in header.attrs:
            raise ExrCorruptError(f"tiled part {index} has no 'tiles' attribute")
        tiles = _parse_tiles(_attr_reader(buf, header, "tiles"))
    envmap = None
    if "envmap" in header.attrs:
        envmap = _attr_reader(buf, header, "envmap").u8("envmap")
    chunk_count = _chunk_count(storage, compression, data_window, tiles)
    if "chunkCount" in header.attrs:
        declared = _attr_reader(buf, header, "chunkCount").i32("chunkCount")
        if declared != chunk_count:
            raise ExrCorruptError(
                f"part {index} declares chunkCount {declared}, its header implies {chunk_count}"
            )
    elif multipart:
        raise ExrCorruptError(f"part {index} of a multi-part file has no 'chunkCount'")
    name = None
    if "name" in header.attrs:
        r = _attr_reader(buf, header, "name")
        name = bytes(buf[r.pos : r.end]).decode("utf-8", "replace")
    return ExrPartInfo(
        index=index,
        name=name,
        storage=storage,
        channels=channels,
        compression=compression,
        data_window=data_window,
        display_window=display_window,
        line_order=line_order,
        tiles=tiles,
        envmap=envmap,
        chunk_count=chunk_count,
        attribute_types={k: v[0] for k, v in header.attrs.items()},
    )


# ----------------------------------------------------------------------------------------------
# offset tables and chunk headers


def _bytes_per_pixel(part: ExrPartInfo) -> int:
    return sum(c.nbytes for c in part.channels)


def _scanline_chunks(part: ExrPartInfo) -> Iterator[tuple[tuple[int, ...], int]]:
    """Expected `(chunk header coordinates, unpacked bytes)` per offset-table entry, in order."""
    lines = LINES_PER_CHUNK[part.compression]
    y_min, y_max = part.data_window[1], part.data_window[3]
    row_bytes = _bytes_per_pixel(part) * part.width
    for y in range(y_min, y_max + 1, lines):
        yield (y,), row_bytes * (min(y + lines - 1, y_max) - y + 1)


def _tile_chunks(part: ExrPartInfo, tiles: ExrTiles) -> Iterator[tuple[tuple[int, ...], int]]:
    bpp = _bytes_per_pixel(part)
    for lx, ly, lw, lh in tile_levels(part.width, part.height, tiles):
        for ty in range(-(-lh // tiles.y_size)):
            th = min(tiles.y_size, lh - ty * tiles.y_size)
            for tx in range(-(-lw // tiles.x_size)):
                tw = min(tiles.x_size, lw - tx * tiles.x_size)
                yield (tx, ty, lx, ly), bpp * tw * th


def _check_chunks(
    buf: mmap.mmap | bytes,
    part: ExrPartInfo,
    offsets: tuple[int, ...],
    table_end: int,
    multipart: bool,
) -> None:
    if part.tiles is not None:
        expected, n_coords = _tile_chunks(part, part.tiles), 4
    else:
        expected, n_coords = _scanline_chunks(part), 1
    fmt = "<" + "i" * (int(multipart) + n_coords + 1)
    header_size = struct.calcsize(fmt)
    for i, ((coords, unpacked), offset) in enumerate(zip(expected, offsets, strict=True)):
        if offset < table_end or offset + header_size > len(buf):
            raise ExrCorruptError(
                f"part {part.index}: chunk {i} offset {offset} lies outside the file "
                f"(data starts at {table_end}, file has {len(buf)} bytes)"
            )
        values = struct.unpack_from(fmt, buf, offset)
        if multipart and values[0] != part.index:
            raise ExrCorruptError(
                f"part {part.index}: chunk {i} claims to belong to part {values[0]}"
            )
        found, size = values[int(multipart) : -1], values[-1]
        if tuple(found) != coords:
            raise ExrCorruptError(
                f"part {part.index}: chunk {i} has coordinates {tuple(found)}, expected {coords}"
            )
        if size <= 0 or offset + header_size + size > len(buf):
            raise ExrCorruptError(
                f"part {part.index}: chunk {i} claims {size} bytes of data at offset "
                f"{offset + header_size}, beyond the end of the file ({len(buf)} bytes)"
            )
        if part.compression == 0 and size != unpacked:
            raise ExrCorruptError(
                f"part {part.index}: uncompressed chunk {i} holds {size} bytes, expected {unpacked}"
            )


# ----------------------------------------------------------------------------------------------
# entry point


def _read_version(r: _Reader) -> tuple[int, int]:
    magic, version_field = r.unpack("<iI", "magic number and version")
    if magic != MAGIC:
        raise ExrCorruptError("not an OpenEXR file (bad magic number)")
    version, flags = version_field & _VERSION_MASK, version_field & ~_VERSION_MASK
    if version != 2:
        raise ExrCorruptError(f"unsupported OpenEXR file version {version}", unsupported=True)
    if flags & ~_VALID_FLAGS:
        raise ExrCorruptError(f"unknown version flags {flags:#x}")
    if flags & _MULTI_PART_FLAG and flags & _TILED_FLAG:
        raise ExrCorruptError("the single-part tiled flag is set in a multi-part file")
    if flags & _NON_IMAGE_FLAG and not flags & _MULTI_PART_FLAG:
        raise ExrCorruptError("the file holds deep (non-image) data", unsupported=True)
    return version, flags


def _validate_buffer(buf: mmap.mmap | bytes) -> ExrFileInfo:
    r = _Reader(buf)
    version, flags = _read_version(r)
    multipart = bool(flags & _MULTI_PART_FLAG)
    max_len = 255 if flags & _LONG_NAMES_FLAG else 31
    headers = [_read_header(r, max_len)]
    if multipart:
        while True:
            if not headers[-1].attrs:
                headers.pop()  # the empty header that ends the list
                break
            if len(headers) > MAX_PARTS:
                raise ExrCorruptError(f"more than {MAX_PARTS} parts")
            headers.append(_read_header(r, max_len))
    if not headers or not headers[0].attrs:
        raise ExrCorruptError("the file has no header attributes")
    parts = tuple(_part_info(buf, h, i, flags, multipart, max_len) for i, h in enumerate(headers))
    decoded = sum(p.width * p.height * _bytes_per_pixel(p) for p in parts)
    if decoded > MAX_DECODED_BYTES:
        raise ExrCorruptError(
            f"decoding would need {decoded} bytes, above the supported {MAX_DECODED_BYTES}",
            unsupported=True,
        )
    total_chunks = sum(p.chunk_count for p in parts)
    table_end = r.pos + 8 * total_chunks
    if table_end > len(buf):
        raise ExrCorruptError(
            f"truncated: the offset tables need {8 * total_chunks} bytes at offset {r.pos}, "
            f"the file has {len(buf)} bytes"
        )
    for part in parts:
        offsets = struct.unpack_from(f"<{part.chunk_count}Q", buf, r.pos)
        r.pos += 8 * part.chunk_count
        _check_chunks(buf, part, offsets, table_end, multipart)
    return ExrFileInfo(version=version, multipart=multipart, parts=parts, file_size=len(buf))


def validate_exr(path: str | os.PathLike[str]) -> ExrFileInfo:
    """Validate the structure of the OpenEXR file at `path` without decoding pixels.

    Args:
        path: the file.

    Returns:
        The parsed part headers.

    Raises:
        ExrCorruptError: when the file is damaged or uses an unsupported feature (deep data,
            subsampled channels, images beyond `MAX_SIDE` / `MAX_PIXELS`).
        OSError: when the file cannot be opened.
    """
    with open(Path(path), "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        if size < 8:
            raise ExrCorruptError(f"truncated: {size} bytes is too short for an OpenEXR file")
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            return _validate_buffer(buf)


def validate_exr_bytes(data: bytes) -> ExrFileInfo:
    """`validate_exr` for bytes already in memory (used in tests)."""
    if len(data) < 8:
        raise ExrCorruptError(f"truncated: {len(data)} bytes is too short for an OpenEXR file")
    return _validate_buffer(data)
