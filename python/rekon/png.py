"""PNG encoding the way `rekon synth` writes its frames (tools/synth/src/png_writer.cpp): every row filtered with
Up, zlib level 1 Huffman-only (window 15, memLevel 9), one IDAT. The same pixels make byte-identical files, and it
is fast (no match search; 640x480 depth in about 5 ms). 16-bit grey, 8-bit grey and 8-bit RGB."""

from __future__ import annotations

import struct
import zlib

import numpy as np

SIGNATURE = b"\x89PNG\r\n\x1a\n"
FILTER_UP = 2


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def encode(pixels: np.ndarray) -> bytes:
    """pixels: (h, w) uint16, (h, w) uint8 or (h, w, 3) uint8 RGB."""
    if pixels.dtype == np.uint16 and pixels.ndim == 2:
        rows, depth, color_type = pixels.astype(">u2").view(np.uint8).reshape(pixels.shape[0], -1), 16, 0
    elif pixels.dtype == np.uint8 and pixels.ndim == 2:
        rows, depth, color_type = pixels, 8, 0
    elif pixels.dtype == np.uint8 and pixels.ndim == 3 and pixels.shape[2] == 3:
        rows, depth, color_type = pixels.reshape(pixels.shape[0], -1), 8, 2
    else:
        raise ValueError(f"PNG encoding: {pixels.dtype} pixels of shape {pixels.shape} (16-bit grey, 8-bit grey or RGB)")
    h, w = pixels.shape[:2]
    filtered = np.empty((h, rows.shape[1] + 1), dtype=np.uint8)
    filtered[:, 0] = FILTER_UP
    filtered[0, 1:] = rows[0]
    np.subtract(rows[1:], rows[:-1], out=filtered[1:, 1:], dtype=np.uint8, casting="unsafe")
    z = zlib.compressobj(1, zlib.DEFLATED, 15, 9, zlib.Z_HUFFMAN_ONLY)
    data = z.compress(filtered.tobytes()) + z.flush()
    header = struct.pack(">IIBBBBB", w, h, depth, color_type, 0, 0, 0)
    return SIGNATURE + _chunk(b"IHDR", header) + _chunk(b"IDAT", data) + _chunk(b"IEND", b"")
