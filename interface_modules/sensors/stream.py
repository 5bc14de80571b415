"""The common output of every sensor model: samples at their sampling times, before encoding."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class SampleStream:
    """Samples of one interface module.

    ``t_s`` are sampling times in seconds from the scenario start; ``values`` maps a wire field name
    (``ax``, ``speed``, ``lat``...) to an array of the same length; ``send`` says which samples are
    actually sent (dropouts, silent faults); ``events`` are (t_s, kind, detail) the model produced.
    """

    module: str
    t_s: np.ndarray
    values: dict[str, np.ndarray]
    send: np.ndarray
    events: list[tuple[float, str, str]] = field(default_factory=list)
    truth: dict[str, np.ndarray] = field(default_factory=dict)  #: error-free values, for tests and analysis

    def __len__(self) -> int:
        return int(self.t_s.size)
