"""Messages between :mod:`~torchrl_ahrs.sandbox.isolation` and the worker: 4-byte length + payload.

Example:
    >>> import io
    >>> stream = io.BytesIO()
    >>> write_message(stream, b"{}")
    >>> _ = stream.seek(0)
    >>> read_message(stream), read_message(stream)
    (b'{}', None)
"""

from __future__ import annotations

import struct
from typing import BinaryIO

HEADER = struct.Struct("!I")  # big-endian payload length


def read_message(stream: BinaryIO) -> bytes | None:
    """One length-prefixed message, or None at end of stream."""
    header = stream.read(HEADER.size)
    if len(header) < HEADER.size:
        return None
    (length,) = HEADER.unpack(header)
    payload = stream.read(length)
    return payload if len(payload) == length else None


def write_message(stream: BinaryIO, payload: bytes) -> None:
    """Writes one length-prefixed message and flushes."""
    stream.write(HEADER.pack(len(payload)) + payload)
    stream.flush()
