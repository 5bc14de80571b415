"""Exceptions of the ``track_db`` package."""


class TrackDbError(Exception):
    """Base class of every error raised by the track database package."""


class ImportFailed(TrackDbError):
    """An import was rejected; nothing was written. The message names the feature/row and the reason."""


class SchemaError(TrackDbError):
    """The file is not a track database, or its schema version is unknown."""


class QueryError(TrackDbError):
    """A query cannot be answered (unknown line id, arc length out of range, ...)."""


BASE_ERROR = TrackDbError
