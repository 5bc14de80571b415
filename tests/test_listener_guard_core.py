"""listener.guard_core: the output guard's compiled rule, per estimate (OutputGuard) and in one loop
(OutputGuard.first_refused, the fast replay's), against a plain Python statement of the rule of
docs/listener.md ("Plausibility"): off-line and implausible-step decisions on arbitrary sequences."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from listener.config import PlausibilityConfig
from listener.plausibility import IMPLAUSIBLE_STEP, OFF_LINE, OutputGuard

LIMITS = {3: (1200.0, 25.0), 7: (80.0, 10.0), 1_000_000_007: (5000.0, 40.0)}


@dataclass(frozen=True)
class Est:
    epoch_s: float
    arc_length_m: float
    line_id: int | None
    sigma_s_m: float


class Oracle:
    """The rule as docs/listener.md states it, in plain Python (the guard before it was compiled)."""

    def __init__(self, limits, cfg) -> None:
        self.limits, self.cfg, self.last = limits, cfg, None

    def check(self, e):
        if not self.cfg.enabled or e.line_id is None:
            return None
        length, vmax = self.limits.get(e.line_id, (math.inf, self.cfg.max_speed_mps))
        m = self.cfg.arc_margin_m
        if not -m <= e.arc_length_m <= length + m:
            return OFF_LINE
        if self.last is not None and self.last.line_id == e.line_id:
            sigma = self.last.sigma_s_m if math.isfinite(self.last.sigma_s_m) else 0.0
            bound = vmax * self.cfg.speed_margin * abs(e.epoch_s - self.last.epoch_s) + (
                self.cfg.step_allowance_m) + 3.0 * sigma
            if not abs(e.arc_length_m - self.last.arc_length_m) <= bound:
                return IMPLAUSIBLE_STEP
        return None


# arcs around the lines' ends and near each other, epochs a few seconds apart: the bounds (length,
# speed x time, the allowance, 3 sigma) all decide some steps
arcs = st.one_of(st.integers(-1200, 14000).map(lambda i: i / 10.0),
                 st.integers(1000, 2600).map(lambda i: i / 10.0), st.floats(-1e4, 1e4),
                 st.sampled_from([math.nan, math.inf, -math.inf]))
ests = st.lists(
    st.builds(Est, st.integers(0, 400).map(lambda i: i / 100.0), arcs,
              st.sampled_from([None, 3, 3, 7, 9, 1_000_000_007]),
              st.one_of(st.integers(0, 500).map(lambda i: i / 10.0), st.just(math.nan))),
    max_size=40,
)


@settings(max_examples=300, deadline=None)
@given(ests, st.booleans(), st.sampled_from([None, 5, 17]))
def test_guard_equals_the_rule_estimate_by_estimate(seq, enabled, reset_at):
    cfg = PlausibilityConfig(enabled=enabled)
    guard, oracle = OutputGuard(LIMITS, cfg), Oracle(LIMITS, cfg)
    for k, e in enumerate(seq):
        if k == reset_at:
            guard.reset()
            oracle.last = None
        assert guard.check(e) == oracle.check(e), (k, e)
        guard.sent(e)
        oracle.last = e


@settings(max_examples=300, deadline=None)
@given(ests)
def test_first_refused_is_the_resilience_stage_vetting_each_output(seq):
    """As listener.resilience vets and sends: checked when the epoch and arc are finite, then sent."""
    cfg = PlausibilityConfig()
    oracle = Oracle(LIMITS, cfg)
    want = -1
    for k, e in enumerate(seq):
        if math.isfinite(e.epoch_s) and math.isfinite(e.arc_length_m) and oracle.check(e) is not None:
            want = k
            break
        oracle.last = e
    line = np.array([-1 if e.line_id is None else e.line_id for e in seq], dtype=np.int64)
    cols = [np.array([getattr(e, f) for e in seq], dtype=np.float64)
            for f in ("epoch_s", "arc_length_m", "sigma_s_m")]
    assert OutputGuard(LIMITS, cfg).first_refused(line, *cols) == want


def test_a_refused_step_and_an_off_line_output():
    guard = OutputGuard(LIMITS, PlausibilityConfig())
    guard.sent(Est(10.0, 100.0, 3, 0.5))
    assert guard.check(Est(11.0, 101.0, 3, 0.5)) is None
    assert guard.check(Est(11.0, 400.0, 3, 0.5)) == IMPLAUSIBLE_STEP
    assert guard.check(Est(11.0, 400.0, 7, 0.5)) == OFF_LINE  # line 7 is 80 m long
    assert guard.check(Est(11.0, 400.0, 9, 0.5)) is None  # another line: no step compared, no length
    guard.reset()
    assert guard.check(Est(11.0, 400.0, 3, 0.5)) is None


def test_the_bound_is_speed_time_allowance_and_three_sigma_of_the_last_sent():
    guard = OutputGuard(LIMITS, PlausibilityConfig())  # line 3: 25 m/s x 1.2; allowance 25 m
    guard.sent(Est(10.0, 100.0, 3, 10.0))
    assert guard.check(Est(12.0, 100.0 + 60.0 + 25.0 + 29.9, 3, 0.0)) is None  # 60 + 25 + 30 m
    assert guard.check(Est(12.0, 100.0 + 60.0 + 25.0 + 30.1, 3, 0.0)) == IMPLAUSIBLE_STEP
    assert guard.check(Est(8.0, 100.0 - 60.0 - 25.0 - 30.1, 3, 0.0)) == IMPLAUSIBLE_STEP  # |dt|, |ds|
    guard.sent(Est(10.0, 100.0, 3, math.nan))  # a sigma that is not finite counts as 0
    assert guard.check(Est(10.0, 124.9, 3, 0.0)) is None
    assert guard.check(Est(10.0, 125.1, 3, 0.0)) == IMPLAUSIBLE_STEP
    assert guard.check(Est(10.0, 1250.1, 3, 0.0)) == OFF_LINE  # 1200 m + the 50 m margin
    assert guard.check(Est(10.0, -50.1, 3, 0.0)) == OFF_LINE


def test_guard_equals_the_rule_on_a_seeded_random_walk():
    """20,000 outputs as a random walk along the lines (steps near every bound), some without a line
    or with a NaN arc or sigma, a reset now and then: every decision is the rule's."""
    rng = np.random.default_rng(11)
    cfg = PlausibilityConfig()
    guard, oracle = OutputGuard(LIMITS, cfg), Oracle(LIMITS, cfg)
    t, s = 0.0, 100.0
    seen = {None: 0, OFF_LINE: 0, IMPLAUSIBLE_STEP: 0}
    for k in range(20_000):
        t += float(rng.uniform(0.0, 2.0))
        s = float(np.clip(s + rng.normal(0.0, 40.0), -150.0, 1300.0))
        line = [3, 3, 3, 7, None, 9][int(rng.integers(6))]
        arc = math.nan if rng.random() < 0.02 else s
        sigma = math.nan if rng.random() < 0.05 else float(rng.uniform(0.0, 30.0))
        e = Est(t, arc, line, sigma)
        if rng.random() < 0.01:
            guard.reset()
            oracle.last = None
        got = guard.check(e)
        assert got == oracle.check(e), (k, e)
        seen[got] += 1
        guard.sent(e)
        oracle.last = e
    assert min(seen.values()) > 100, seen  # every decision taken many times: the comparison is not vacuous
