"""Exceptions of the ``tools`` package (replay, fault injection, benchmarks)."""


class ToolError(Exception):
    """Base class of every error raised by the tools."""


class CaptureError(ToolError):
    """A capture file cannot be read (message says which file, which packet and why)."""


BASE_ERROR = ToolError
