"""The certified oracle's pipe to its worker processes (minirt.oracles.exact.worker): each message an 8-byte
little-endian length and that many bytes (a pickle, from the process at the other end only)."""

from __future__ import annotations

import struct

HEADER = struct.Struct("<Q")


def read_message(f) -> bytes | None:
    """One message from a binary stream (None at its end)."""
    head = f.read(HEADER.size)
    if len(head) < HEADER.size:
        return None
    (n,) = HEADER.unpack(head)
    data = f.read(n)
    if len(data) < n:
        return None
    return data


def write_message(f, data: bytes) -> None:
    f.write(HEADER.pack(len(data)))
    f.write(data)
    f.flush()
