"""Exceptions of the ``interface_modules`` package (simulator, sensor senders)."""


class SimError(Exception):
    """Base class of every error raised by the simulator and the interface modules."""


class ScenarioError(SimError):
    """A scenario file is invalid (message says which key and why)."""


BASE_ERROR = SimError
