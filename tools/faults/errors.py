"""Exceptions of the fault-injection tools (subclasses of :class:`tools.errors.ToolError`)."""

from __future__ import annotations

from tools.errors import ToolError


class FaultConfigError(ToolError):
    """An impairment profile or a campaign file is invalid (the message names the key and why)."""


class CampaignError(ToolError):
    """A campaign scenario could not be run (a process failed to start, a file is missing...)."""


class ModeUnsupported(CampaignError):
    """A row cannot run in this mode or on this machine (the row is skipped with this reason)."""


BASE_ERROR = ToolError
