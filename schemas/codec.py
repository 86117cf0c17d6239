"""Encoding and decoding of wire messages (msgpack via msgspec).

One cached ``Decoder`` per type. Every failure to decode or validate raises
:class:`RejectedMessage` with msgspec's explanation (which names the offending field), and
nothing else: callers count and log it and carry on.
"""

from __future__ import annotations

import functools
from typing import TypeVar, Union

import msgspec

from .base import Message
from .messages import MESSAGE_TYPES

__all__ = ["RejectedMessage", "decode", "decode_any", "decoder", "encode"]

M = TypeVar("M", bound=Message)

_encoder = msgspec.msgpack.Encoder()
#: Any message, told apart by its ``type`` tag.
AnyMessage = Union[MESSAGE_TYPES]  # noqa: UP007  (a runtime tuple cannot use |)


class RejectedMessage(ValueError):
    """A payload that is not a valid message of the expected type."""


def encode(message: Message) -> bytes:
    """Serialise a message to msgpack bytes."""
    return _encoder.encode(message)


@functools.cache
def decoder(message_type: type[M]) -> msgspec.msgpack.Decoder[M]:
    """The (cached) decoder of one message type."""
    return msgspec.msgpack.Decoder(message_type)


def decode(message_type: type[M], payload: bytes | bytearray | memoryview) -> M:
    """Decode and validate ``payload`` as ``message_type``.

    Arrays in the result are views into ``payload`` (no copy), so keep it alive and unmodified
    for as long as the message is used.
    """
    try:
        return decoder(message_type).decode(payload)
    except msgspec.DecodeError as exc:  # ValidationError is a DecodeError
        raise RejectedMessage(f"{message_type.__name__}: {exc}") from None
    except (ValueError, TypeError, OverflowError) as exc:  # defensive: never leak other errors
        raise RejectedMessage(f"{message_type.__name__}: {exc}") from None


def decode_any(payload: bytes | bytearray | memoryview) -> Message:
    """Decode a payload of any message type (by its tag)."""
    return decode(AnyMessage, payload)  # type: ignore[arg-type]
