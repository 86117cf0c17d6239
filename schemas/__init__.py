"""followbot's wire language: messages, key expressions and the codec.

See docs/messages.md for every topic, field and unit.
"""

from .base import SCHEMA_VERSION, Array, Message
from .codec import RejectedMessage, decode, decode_any, encode
from .keys import TOPICS, Keys, topic_type
from .messages import *  # noqa: F403
from .messages import __all__ as _messages_all

__all__ = [
    "SCHEMA_VERSION",
    "TOPICS",
    "Array",
    "Keys",
    "Message",
    "RejectedMessage",
    "decode",
    "decode_any",
    "encode",
    "topic_type",
    *_messages_all,
]
