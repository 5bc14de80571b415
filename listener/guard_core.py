"""The output guard's rule, once: compiled kernels over an explicit state (sans-I/O).

:class:`listener.plausibility.OutputGuard` (the listener, per estimate) and the fast replay
(``tools.fast_replay.resilience_reason``: every new estimate of a capture in one compiled loop,
:func:`first_refused`) run these same functions on the same kind of state. The rule is described in
:mod:`listener.plausibility`: the published arc length stays on its line ([-arc_margin_m, length +
arc_margin_m]) and moves, from one sent output to the next on the same line, no more than
``max_speed x speed_margin x dt + step_allowance_m + 3 sigma`` (sigma of the last sent output).

The kernels are decorated with :func:`sfa.engine.njit`: ``sfa listen`` runs the copies compiled ahead
of time into the engine extension (:func:`check`, :func:`sent`), every other process numba's JIT of
the same source, which computes the same bits.

State (:func:`new_state`): ``g`` (float64) holds the configuration ``G_*``, the last sent output, and
per line of the track (sorted by line id) its length and maximum speed; ``gi`` (int64) the last sent
output's line and the sorted line ids.
"""

from __future__ import annotations

import math

import numpy as np

from sfa.engine import njit

OK = 0  #: check: publishable
OFF_LINE = 1  #: check: the arc length is off its line
IMPLAUSIBLE_STEP = 2  #: check: the arc length moved more than the bound since the last sent output

# g: float64 slots
G_ENABLED = 0  #: plausibility.enabled (0/1)
G_MARGIN = 1  #: arc_margin_m [m]
G_SPEED_MARGIN = 2  #: speed_margin [-]
G_STEP = 3  #: step_allowance_m [m]
G_VMAX = 4  #: max_speed_mps: a line without its own limit [m/s]
G_HAS_LAST = 5  #: an output was sent since the start or the last (re)initialisation (0/1)
G_LAST_HAS_LINE = 6  #: that output had a line (0/1)
G_LAST_EPOCH = 7  #: its epoch [s]
G_LAST_ARC = 8  #: its arc length [m]
G_LAST_SIGMA = 9  #: its sigma [m]
G_LINES = 10  #: n lengths [m], then n maximum speeds [m/s], in the order of the sorted ids
# gi: int64 slots
GI_LAST_LINE = 0  #: the last sent output's line id
GI_N = 1  #: lines with limits
GI_IDS = 2  #: n sorted line ids


def new_state(limits: dict[int, tuple[float, float]], cfg) -> tuple[np.ndarray, np.ndarray]:
    """(g, gi) of a guard that has sent nothing, for ``limits`` (line_id -> (length [m], maximum speed
    [m/s]), :func:`listener.plausibility.line_limits`) and ``cfg`` (a PlausibilityConfig)."""
    ids = sorted(int(k) for k in limits)
    n = len(ids)
    g = np.zeros(G_LINES + 2 * n)
    g[G_ENABLED] = 1.0 if cfg.enabled else 0.0
    g[G_MARGIN] = cfg.arc_margin_m
    g[G_SPEED_MARGIN] = cfg.speed_margin
    g[G_STEP] = cfg.step_allowance_m
    g[G_VMAX] = cfg.max_speed_mps
    for i, k in enumerate(ids):
        g[G_LINES + i], g[G_LINES + n + i] = limits[k]
    gi = np.zeros(GI_IDS + n, dtype=np.int64)
    gi[GI_N] = n
    gi[GI_IDS:] = ids
    return g, gi


def reset(g: np.ndarray) -> None:
    """An accepted (re)initialisation: the next output is not compared with the last one."""
    g[G_HAS_LAST] = 0.0


@njit(cache=True, _nrt=False)
def _line_index(gi, line):
    """Index of ``line`` among the sorted ids, or -1."""
    lo = 0
    hi = gi[GI_N]
    while lo < hi:
        mid = (lo + hi) // 2
        v = gi[GI_IDS + mid]
        if v < line:
            lo = mid + 1
        elif v > line:
            hi = mid
        else:
            return mid
    return -1


@njit(cache=True, _nrt=False)
def check(g, gi, line, epoch_s, arc_length_m):
    """Whether an estimate on ``line`` (it has one) at ``epoch_s`` with ``arc_length_m`` may be
    published: OK, OFF_LINE or IMPLAUSIBLE_STEP (pure: nothing is changed)."""
    if g[G_ENABLED] == 0.0:
        return OK
    k = _line_index(gi, line)
    if k >= 0:
        length = g[G_LINES + k]
        vmax = g[G_LINES + gi[GI_N] + k]
    else:
        length = math.inf
        vmax = g[G_VMAX]
    s = arc_length_m
    margin = g[G_MARGIN]
    if not (-margin <= s and s <= length + margin):
        return OFF_LINE
    if g[G_HAS_LAST] != 0.0 and g[G_LAST_HAS_LINE] != 0.0 and gi[GI_LAST_LINE] == line:
        dt = abs(epoch_s - g[G_LAST_EPOCH])
        sigma = g[G_LAST_SIGMA] if math.isfinite(g[G_LAST_SIGMA]) else 0.0
        bound = vmax * g[G_SPEED_MARGIN] * dt + g[G_STEP] + 3.0 * sigma
        if not abs(s - g[G_LAST_ARC]) <= bound:
            return IMPLAUSIBLE_STEP
    return OK


@njit(cache=True, _nrt=False)
def sent(g, gi, has_line, line, epoch_s, arc_length_m, sigma_s_m):
    """An output was sent: the next one on the same line is compared with it."""
    g[G_HAS_LAST] = 1.0
    g[G_LAST_HAS_LINE] = 1.0 if has_line else 0.0
    gi[GI_LAST_LINE] = line if has_line else 0
    g[G_LAST_EPOCH] = epoch_s
    g[G_LAST_ARC] = arc_length_m
    g[G_LAST_SIGMA] = sigma_s_m


@njit(cache=True, _nrt=False)
def first_refused(g, gi, line, epoch_s, arc_length_m, sigma_s_m):
    """The outputs ``k`` (``line[k]`` = -1: none, as tools.replay records it) sent one after the other,
    each vetted as the listener's resilience stage vets it (checked when its epoch and arc length are
    finite and it has a line, then sent): the index of the first the guard refuses, or -1 when it
    passes them all."""
    for k in range(line.shape[0]):
        has_line = line[k] != -1
        if has_line and math.isfinite(epoch_s[k]) and math.isfinite(arc_length_m[k]):
            if check(g, gi, line[k], epoch_s[k], arc_length_m[k]) != OK:
                return k
        sent(g, gi, has_line, line[k], epoch_s[k], arc_length_m[k], sigma_s_m[k])
    return -1
