"""Building blocks shared by every wire message: bounded scalar types, the message base, arrays.

Wire rules (DESIGN.md "Conventions"):

* Every message is a msgspec Struct with an explicit ``tag`` (the ``type`` field on the wire),
  carries ``schema_version``, ``stamp_ns`` (integer nanoseconds of the *sensor data it derives
  from*), ``frame_id`` and ``seq``.
* New fields always get defaults and unknown fields are ignored, so old readers accept newer
  writers (msgspec's schema-evolution rules). ``forbid_unknown_fields`` is never set here.
* Arrays travel as raw little-endian bytes with dtype and shape (:class:`Array`); decoding gives
  a ``memoryview`` into the received payload and :meth:`Array.numpy` wraps it without copying.
* Validation happens on decode: bounds on scalars are msgspec ``Meta`` constraints (checked in
  C, and they reject NaN and inf), cross-field rules live in ``__post_init__`` (msgspec runs it
  after decoding; a ``ValueError`` there becomes a ``msgspec.ValidationError``).
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import msgspec
import numpy as np

__all__ = [
    "MAX_ITEMS",
    "MAX_NAME_LEN",
    "SCHEMA_VERSION",
    "Angle",
    "Array",
    "Count",
    "Finite",
    "Message",
    "Name",
    "NonNegative",
    "Stamp",
]

#: Bumped when a change is not backward compatible (a field removed, renamed or retyped).
#: Adding an optional field is compatible and does not bump it.
SCHEMA_VERSION = 1

#: Largest magnitude accepted for a "finite" float. Comparisons against it fail for NaN and for
#: +-inf, so ``Finite`` doubles as the finiteness check.
_BIG = 1e12
#: Bound on list lengths (candidates, tracks, people) and mapping sizes in any message.
MAX_ITEMS = 256
#: Bound on names and free-text fields.
MAX_NAME_LEN = 256
#: Bound on the byte size of one array or image payload (4096 x 4096 x 3 bytes).
MAX_BYTES = 4096 * 4096 * 3

Finite = Annotated[float, msgspec.Meta(ge=-_BIG, le=_BIG, description="finite float")]
NonNegative = Annotated[float, msgspec.Meta(ge=0.0, le=_BIG, description="finite float >= 0")]
Angle = Annotated[
    float, msgspec.Meta(ge=-2 * math.pi, le=2 * math.pi, description="angle in radians")
]
Stamp = Annotated[int, msgspec.Meta(ge=0, le=2**63 - 1, description="nanoseconds")]
Count = Annotated[int, msgspec.Meta(ge=0, le=2**63 - 1)]
Name = Annotated[str, msgspec.Meta(max_length=MAX_NAME_LEN)]

#: dtypes an :class:`Array` may carry, all little-endian (or byte-sized).
DType = Literal["<f4", "<f8", "|u1", "<u2", "<i4", "<i8"]
_ITEMSIZE = {"<f4": 4, "<f8": 8, "|u1": 1, "<u2": 2, "<i4": 4, "<i8": 8}
_MAX_DIMS = 4


class Message(msgspec.Struct, kw_only=True, tag_field="type"):
    """Fields every message carries. Subclasses set ``tag="..."`` explicitly."""

    stamp_ns: Stamp
    """Stamp of the sensor data this message derives from (ns; sensor or sim clock)."""
    frame_id: Name = ""
    """Coordinate frame of the message's positions (REP-103: base_link, base_laser, odom...)."""
    seq: Count = 0
    """Publisher's sequence number, to count losses."""
    schema_version: Annotated[int, msgspec.Meta(ge=1)] = SCHEMA_VERSION
    """Version of the message definitions the publisher was built with."""


class Array(msgspec.Struct, kw_only=True):
    """An n-d numeric array as raw little-endian bytes.

    Build one with :meth:`from_numpy`; read it with :meth:`numpy` (a read-only view into the
    decoded payload, no copy).
    """

    dtype: DType
    shape: Annotated[list[Annotated[int, msgspec.Meta(ge=0)]], msgspec.Meta(max_length=_MAX_DIMS)]
    data: memoryview

    def __post_init__(self) -> None:
        n = _ITEMSIZE[self.dtype]
        for dim in self.shape:
            n *= dim
        if n > MAX_BYTES:
            raise ValueError(f"array of {n} bytes exceeds the {MAX_BYTES}-byte bound")
        if len(self.data) != n:
            raise ValueError(
                f"array data has {len(self.data)} bytes, shape {self.shape} of {self.dtype} "
                f"needs {n}"
            )

    @classmethod
    def from_numpy(cls, array: np.ndarray) -> Array:
        """Wrap ``array`` (converted to little-endian C order only if it is not already)."""
        dt = array.dtype.newbyteorder("<") if array.dtype.itemsize > 1 else array.dtype
        array = np.ascontiguousarray(array, dtype=dt)
        tag = array.dtype.str
        if tag not in _ITEMSIZE:
            raise TypeError(f"dtype {array.dtype} cannot travel; use one of {sorted(_ITEMSIZE)}")
        return cls(dtype=tag, shape=list(array.shape), data=memoryview(array).cast("B"))

    def numpy(self) -> np.ndarray:
        """A read-only view of the data (no copy when decoded from a payload)."""
        return np.frombuffer(self.data, dtype=self.dtype).reshape(self.shape)

    def __len__(self) -> int:
        return self.shape[0] if self.shape else 1


def require(condition: bool, message: str) -> None:
    """Raise ``ValueError(message)`` unless ``condition``; used by ``__post_init__`` checks."""
    if not condition:
        raise ValueError(message)
