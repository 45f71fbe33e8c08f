"""Byte-reproducible image headers: no dates or timings in the EXR and PNG files Blender writes.

Blender stamps the render date, the wall-clock render time, the frame and the .blend name into the
metadata of every image it saves, and Cycles adds its own per-render timings
(`cycles.<view layer>.render_time`, `.synchronization_time`, `.total_time`). Two renders of the same
plan then hold identical pixels in different bytes, so their sha256 differ. The worker turns Blender's
stamps off in the scene (`disable_stamps`, in `_scene`), and Cycles' timings, which no setting turns
off, are removed from each file after Blender wrote it and before it is renamed into place
(`strip_volatile_metadata`). Pixels and every other attribute stay as Blender wrote them.

This module imports numpy and OpenEXR only (no bpy), so it is testable without Blender.
"""

import struct
from pathlib import Path

import numpy as np

# Stamp fields of Blender (`BKE_stamp_info_callback`) that change from run to run or machine to machine.
_VOLATILE_STAMPS = frozenset({"Date", "Time", "RenderTime", "Memory", "Hostname", "File", "Frame"})
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_TEXT_CHUNKS = (b"tEXt", b"zTXt", b"iTXt")


def is_volatile_key(key: str) -> bool:
    """Whether an image metadata key holds a date, a timing or a per-machine value.

    Args:
        key: an EXR header attribute name or a PNG text keyword.

    Returns:
        True for Blender's date/time/render-time/memory/hostname/file/frame stamps and for Cycles'
        `cycles.*_time` statistics; False for everything else (`Software`, `cycles.*.samples`, the
        EXR structural attributes, ...).
    """
    return key in _VOLATILE_STAMPS or (key.startswith("cycles.") and key.endswith("_time"))


def strip_volatile_metadata(path: Path) -> bool:
    """Remove volatile metadata (see `is_volatile_key`) from an EXR or PNG file, in place.

    PNG: the `tEXt`/`zTXt`/`iTXt` chunks with a volatile keyword are dropped; every other chunk (the
    compressed pixels included) is kept byte for byte. EXR: the file is rewritten through OpenEXR with
    the same channels, pixel types, compression and remaining attributes (single-part files
    only; Blender's single-layer saves are single-part). A file without volatile
    metadata is not touched. Not atomic: call it on the temporary of an atomic write.

    Args:
        path: an `.exr` or `.png` file (decided by its first bytes, not its suffix).

    Returns:
        Whether the file was changed.
    """
    path = Path(path)
    with path.open("rb") as fh:
        magic = fh.read(8)
    if magic == _PNG_SIGNATURE:
        return _strip_png(path)
    if magic[:4] == b"\x76\x2f\x31\x01":
        return _strip_exr(path)
    return False


def _png_keyword(chunk_type: bytes, data: bytes) -> str:
    if chunk_type not in _PNG_TEXT_CHUNKS:
        return ""
    return data.split(b"\x00", 1)[0].decode("latin-1")


def _strip_png(path: Path) -> bool:
    data = path.read_bytes()
    kept = [_PNG_SIGNATURE]
    pos, changed = len(_PNG_SIGNATURE), False
    while pos + 8 <= len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        chunk_type = data[pos + 4 : pos + 8]
        end = pos + 12 + length
        chunk = data[pos:end]
        if is_volatile_key(_png_keyword(chunk_type, data[pos + 8 : pos + 8 + length])):
            changed = True
        else:
            kept.append(chunk)
        pos = end
    if pos < len(data):  # trailing bytes after the last chunk: keep them as they were
        kept.append(data[pos:])
    if changed:
        path.write_bytes(b"".join(kept))
    return changed


def _strip_exr(path: Path) -> bool:
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        if len(f.parts) != 1:  # Blender's single-layer saves are single-part; leave others alone
            return False
        header = dict(f.header())
        channels = {name: np.array(ch.pixels) for name, ch in f.channels().items()}
    if not any(is_volatile_key(k) for k in header):
        return False
    header = {k: v for k, v in header.items() if k != "channels" and not is_volatile_key(k)}
    with OpenEXR.File(header, channels) as out:
        out.write(str(path))
    return True
