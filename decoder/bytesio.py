"""Bounds-checked little-endian reading (decoder) and the matching writer (encoder).

Every read checks the bytes it needs are present, so a truncated or hostile payload raises
:class:`GszFormatError` instead of an IndexError or a huge allocation.
"""
from __future__ import annotations

import struct

import numpy as np

from .errors import GszFormatError


class Reader:
    def __init__(self, data, what: str = "chunk"):
        self.mv = memoryview(data).cast("B") if not isinstance(data, memoryview) else data.cast("B")
        self.pos = 0
        self.what = what

    @property
    def remaining(self) -> int:
        return len(self.mv) - self.pos

    def _need(self, n: int) -> None:
        if n < 0 or self.pos + n > len(self.mv):
            raise GszFormatError(f"{self.what}: truncated (needs {n} more bytes at offset {self.pos}, "
                                 f"has {self.remaining})")

    def _unpack(self, fmt: str):
        size = struct.calcsize(fmt)
        self._need(size)
        v = struct.unpack_from(fmt, self.mv, self.pos)
        self.pos += size
        return v[0] if len(v) == 1 else v

    def u8(self) -> int: return self._unpack("<B")
    def u16(self) -> int: return self._unpack("<H")
    def u32(self) -> int: return self._unpack("<I")
    def u64(self) -> int: return self._unpack("<Q")
    def f32(self) -> float: return self._unpack("<f")
    def f64(self) -> float: return self._unpack("<d")

    def bytes(self, n: int) -> memoryview:
        self._need(n)
        out = self.mv[self.pos:self.pos + n]
        self.pos += n
        return out

    def array(self, dtype, count: int) -> np.ndarray:
        dt = np.dtype(dtype).newbyteorder("<")
        n = int(count) * dt.itemsize
        return np.frombuffer(self.bytes(n), dtype=dt).astype(dt.newbyteorder("="), copy=True)

    def blob(self) -> memoryview:
        """A u64 length followed by that many bytes."""
        return self.bytes(self.u64())

    def check(self, cond: bool, message: str) -> None:
        if not cond:
            raise GszFormatError(f"{self.what}: {message}")

    def expect_end(self) -> None:
        if self.remaining:
            raise GszFormatError(f"{self.what}: {self.remaining} unexpected trailing bytes")


class Writer:
    def __init__(self):
        self.parts: list[bytes] = []

    def _pack(self, fmt, v):
        self.parts.append(struct.pack(fmt, v))
        return self

    def u8(self, v): return self._pack("<B", int(v))
    def u16(self, v): return self._pack("<H", int(v))
    def u32(self, v): return self._pack("<I", int(v))
    def u64(self, v): return self._pack("<Q", int(v))
    def f32(self, v): return self._pack("<f", float(v))
    def f64(self, v): return self._pack("<d", float(v))

    def bytes(self, b) -> "Writer":
        self.parts.append(bytes(b))
        return self

    def array(self, arr, dtype) -> "Writer":
        self.parts.append(np.ascontiguousarray(arr, dtype=np.dtype(dtype).newbyteorder("<")).tobytes())
        return self

    def blob(self, b) -> "Writer":
        self.u64(len(b))
        return self.bytes(b)

    def getvalue(self) -> bytes:
        return b"".join(self.parts)
