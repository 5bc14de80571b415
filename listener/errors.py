"""Exceptions of the ``listener`` package (wire codec, sequence buffers, service)."""


class ListenerError(Exception):
    """Base class of every error raised by the listener package."""


class ConfigError(ListenerError):
    """The listener or OBCU configuration is invalid (message says which key and why)."""


BASE_ERROR = ListenerError
