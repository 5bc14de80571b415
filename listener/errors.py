"""Exceptions of the ``listener`` package (wire codec, sequence buffers, service)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the enum lives with the codec; errors.py must not import it at run time (no cycle)
    from listener.reject import RejectReason


class ListenerError(Exception):
    """Base class of every error raised by the listener package."""


class ConfigError(ListenerError):
    """The listener or OBCU configuration is invalid (message says which key and why)."""


class CodecError(ListenerError):
    """A wire message broke the protocol. ``reason`` is a closed :class:`RejectReason`, ``detail`` a sentence.

    Callers count rejections per ``reason`` (a ``StrEnum``, so it is also a stable metric label).
    """

    __slots__ = ("reason", "detail")

    def __init__(self, reason: RejectReason, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail

    def __reduce__(self):  # keep reason/detail across pickling (multiprocessing replay workers)
        return (type(self), (self.reason, self.detail))


class DecodeError(CodecError):
    """The peer broke the protocol: a received datagram is malformed or out of range.

    (h11's RemoteProtocolError.)
    """


class EncodeError(CodecError):
    """We broke the protocol: a message we were asked to send is malformed or out of range
    (h11's LocalProtocolError). Never caused by network input."""


class SequenceError(ListenerError):
    """A sequence buffer was called with an impossible argument (a seq outside 0..65535, a bad time).

    Never caused by network input: sequence numbers come from a decoded 16-bit header field.
    """


BASE_ERROR = ListenerError
