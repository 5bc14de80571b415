"""Exceptions of the ``sfa`` filter package. The filter never exits the process."""


class SfaError(Exception):
    """Base class of every error raised by the filter package."""


class FilterConfigError(SfaError):
    """A filter configuration value is missing, of the wrong type or out of range."""


class FilterStateError(SfaError):
    """The filter was asked for something its state cannot give (for example before initialisation)."""


class MeasurementTypeError(SfaError):
    """``TrackFilter.process`` was given something that is not one of the sfa.measurements types."""


BASE_ERROR = SfaError
