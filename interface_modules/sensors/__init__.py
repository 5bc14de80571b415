"""Sensor models: truth trajectory -> time-stamped samples with documented errors (vectorised numpy)."""

from .stream import SampleStream

__all__ = ["SampleStream"]
