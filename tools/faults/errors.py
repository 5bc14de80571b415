"""Exceptions of the fault-injection tools (subclasses of :class:`tools.errors.ToolError`)."""

from __future__ import annotations

from tools.errors import ToolError


class FaultConfigError(ToolError):
    """An impairment profile or a campaign file is invalid (the message names the key and why)."""


class CampaignError(ToolError):
    """A campaign scenario could not be run (a process failed to start, a file is missing...)."""


BASE_ERROR = ToolError
