"""Vital supervision in the pipeline core, scripted time: time-outs on the timer, status and link events,
the latched decay state and its recovery, module vitality (live timing: test_listener_vital_live)."""

from __future__ import annotations

import pytest
from test_listener_pipeline import _datagrams

from interface_modules.presets import GPS_PRESETS, IMU_PRESETS, ODOMETER_PRESETS
from listener.codec import decode_output, decode_output_any
from listener.config import LinkConfig, ListenerConfig, VitalConfig, config_from_dict
from listener.errors import ConfigError
from listener.pipeline import Pipeline
from listener.vital import DecaySupervisor, ModuleHealth
from sfa.measurements import InitMeas
from sfa.synthetic import Profile, generate

IMU, ODO, GPS, CTL = 1, 2, 3, 8  # first payload byte (SENSOR_TYPE)
T0 = 1000.0  # the synthetic runs' first epoch



def _run(track, duration, profile=None, faults=None, seed=5):
    return generate(
        track, 1, duration, IMU_PRESETS["mems-train"], ODOMETER_PRESETS["wheel-odometer"],
        GPS_PRESETS["standalone"], seed=seed, profile=profile, faults=faults,
    )


def _drive(pipe: Pipeline, dgrams, until: float | None = None):
    """Feed datagrams as the event loop would: every timer due before a datagram fires at its own time.
    Returns [(time, payload)] of everything sent and the events, in order."""
    sent: list[tuple[float, bytes]] = []
    events: list[dict] = []

    def timers_until(t: float) -> None:
        for _ in range(100000):
            nxt = pipe.next_timer()
            if nxt is None or nxt > t:
                return
            sent.extend((nxt, p) for p in pipe.handle_timer(nxt))
            events.extend(pipe.take_events())
        raise AssertionError("timer loop did not settle")  # pragma: no cover

    for t, addr, data in dgrams:
        timers_until(t)
        sent.extend((t, p) for p in pipe.receive(data, addr, t))
        events.extend(pipe.take_events())
        if pipe.stopped:
            break
    if until is not None:
        timers_until(until)
    return sent, events


def _drop(dgrams, types, t_from, t_to=float("inf")):
    return [d for d in dgrams if not (d[2][0] in types and t_from <= d[0] - T0 < t_to)]


def _no_stop(dgrams):
    return [d for d in dgrams if d[2][0] != 10]


def _last(dgrams, stype, before):
    return max(t for t, _, p in dgrams if p[0] == stype and t - T0 < before)


def _status_events(events, status=None):
    return [e for e in events if e["event"] == "status" and (status is None or e["status"] == status)]


# ------------------------------------------------------------------ time-outs on the timer
@pytest.mark.parametrize(
    ("silent", "stype", "reason", "status"),
    [
        ("imu", (IMU,), "imu_timeout", "degraded"),
        ("odometer", (ODO,), "odometer_timeout", "degraded"),
        ("gnss", (GPS,), "gnss_timeout", "degraded"),
        ("all", (IMU, ODO, GPS), "no_motion_sensor", "lost"),
    ],
)
def test_a_silent_sensor_is_timed_out_by_the_timer(track, silent, stype, reason, status):
    """The sensor stops at 20 s and nothing else changes: the status event comes from the timer within
    its time-out + 100 ms of its last datagram, names the reason and how long each module was silent;
    on the extended output the OBCU gets the new status at the same moment."""
    dgrams = _no_stop(_datagrams(_run(track, 30.0), start_seq=0))
    cut = _drop(dgrams, stype, 20.0)
    last = max(_last(dgrams, s, 20.0) for s in stype) if silent != "all" else _last(dgrams, ODO, 20.0)
    pipe = Pipeline(track, ListenerConfig(link=LinkConfig(extended=True)))
    # the preset's time-outs (mems-train 0.2 s, wheel odometer 0.5 s, GNSS 3 s); LOST when the later
    # of the two motion sensors times out
    timeout = pipe._timeouts["odometer" if silent == "all" else silent]
    sent, events = _drive(pipe, cut, until=T0 + 26.0)
    after = [e for e in _status_events(events, status) if e["at"] > last]
    assert after, [e for e in events if e["at"] > last]
    ev = after[0]
    assert reason in ev["reasons"]
    delay = ev["at"] - last
    assert timeout <= delay <= timeout + 0.1, delay
    assert ev["since_heard_s"][silent if silent != "all" else "odometer"] == pytest.approx(delay, abs=1e-3)
    code = {"degraded": 2, "lost": 3}[status]
    seen = [t for t, p in sent if t > last and decode_output_any(p).status == code]
    assert seen and seen[0] - last <= timeout + 0.1
    if silent == "imu":
        assert ev["source"] == "timer"  # not waiting for the next measurement


def test_standard_output_stops_when_lost_and_the_link_change_is_an_event(track):
    dgrams = _no_stop(_datagrams(_run(track, 30.0), start_seq=0))
    cut = _drop(dgrams, (IMU, ODO, GPS), 20.0)
    pipe = Pipeline(track, ListenerConfig(link=LinkConfig(degraded_after_s=1.0, down_after_s=2.0)))
    sent, events = _drive(pipe, cut, until=T0 + 30.0)
    lost = _status_events(events, "lost")
    assert lost and lost[0]["source"] == "timer"
    t_lost = lost[0]["at"]
    # nothing after LOST: neither a new estimate nor a retransmission of the last one
    assert not [t for t, _ in sent if t >= t_lost]
    assert any(e["event"] == "decay_entered" and e["cause"] == "lost" for e in events)
    links = [(e["at"], e["state"]) for e in events if e["event"] == "link_state"]
    assert [s for _, s in links][:1] == ["up"]
    assert "degraded" in [s for _, s in links] and "down" in [s for _, s in links]  # no acks at all
    assert all(len(p) == 18 for _, p in sent)
    m = pipe.metrics(T0 + 30.0)
    assert m["vital"]["decay"]["latched"] and m["link"]["withheld"] > 0
    assert m["vital"]["modules"]["imu"]["timed_out"]
    # the metrics say so (issue 19: they kept saying "nominal" for 12 s after the sensors died); the
    # filter section keeps the status of the last estimate produced by a measurement
    assert m["vital"]["status"] == "lost" and "no_motion_sensor" in m["vital"]["reasons"]


def test_clean_run_has_no_timer_work(track):
    """While every sensor keeps to its rate, the time-out deadlines keep moving: no timer check runs,
    no status event beyond the start, nothing withheld."""
    dgrams = _datagrams(_run(track, 30.0), start_seq=0)
    pipe = Pipeline(track, ListenerConfig())
    sent, events = _drive(pipe, dgrams)
    assert pipe.vital_counters["timer_checks"] == 0
    assert pipe.vital_counters["withheld"] == 0
    assert [e["status"] for e in _status_events(events)][:1] == ["nominal"]
    vit = pipe.vitality(dgrams[-1][0])
    assert vit["modules"]["imu"]["rate_hz"] == pytest.approx(100.0, rel=0.05)
    assert vit["modules"]["odometer"]["rate_hz"] == pytest.approx(20.0, rel=0.1)
    assert all(v["rate_ok"] for v in vit["modules"].values())
    assert vit["modules"]["imu"]["sequence"]["lost"] == 0


def test_supervision_off_sends_as_before(track):
    dgrams = _no_stop(_datagrams(_run(track, 30.0), start_seq=0))
    cut = _drop(dgrams, (IMU, ODO, GPS), 20.0)
    on, _ = _drive(Pipeline(track, ListenerConfig()), cut, until=T0 + 25.0)
    off_pipe = Pipeline(track, ListenerConfig(vital=VitalConfig(enabled=False)))
    off, _ = _drive(off_pipe, cut, until=T0 + 25.0)
    assert off_pipe.vital_counters["timer_checks"] == 0
    assert [p for t, p in off if t - T0 < 20.0] == [p for t, p in on if t - T0 < 20.0]
    assert len(off) > len(on)  # the retransmissions of the last estimate after the silence


# ------------------------------------------------------------------ decay
def _with_ground_truth(run, t_rel: float):
    """The run's measurements with a GROUND TRUTH (truth arc length and speed) at T0 + t_rel."""
    import numpy as np

    t = T0 + t_rel
    s = float(np.interp(t, run.t_s, run.s_m))
    v = float(np.interp(t, run.t_s, run.v_mps))
    run.measurements = sorted([*run.measurements, InitMeas(t, s, v, 1)], key=lambda m: m.t_s)
    return run


PROFILE = Profile(segments=((10.0, 0.8), (20.0, 0.0), (10.0, -0.8), (40.0, 0.0)))  # at rest from 40 s


def _decay_world(track, *gt_times):
    run = _run(track, 70.0, profile=PROFILE)
    for t in gt_times:
        run = _with_ground_truth(run, t)
    dgrams = _datagrams(run, start_seq=0)
    dgrams = _drop(dgrams, (IMU, ODO), 15.0, 17.0)  # nothing propagates the state: LOST
    dgrams = _drop(dgrams, (IMU,), 25.0, 26.5)  # a further fault while latched
    return dgrams


def test_decay_is_latched_through_a_further_fault_and_released_only_by_the_recovery(track):
    dgrams = _decay_world(track, 30.0, 50.0)  # GROUND TRUTH while moving (30 s), then at rest (50 s)
    pipe = Pipeline(track, ListenerConfig(vital=VitalConfig(recovery_updates=20)))
    sent, events = _drive(pipe, dgrams)
    kinds = [e["event"] for e in events if e["event"].startswith("decay")]
    entered = next(e for e in events if e["event"] == "decay_entered")
    assert entered["cause"] == "lost" and 15.0 < entered["at"] - T0 < 17.0
    # the IMU's second silence while latched: a further fault, still latched
    assert any(e["event"] == "decay_fault" and "imu_timeout" in e["fault"] for e in events)
    # the GROUND TRUTH while moving is refused; standstill, the one at rest, 20 consistent updates
    rejected = [e for e in events if e["event"] == "decay_recovery_rejected"]
    assert rejected and 29.9 < rejected[0]["at"] - T0 < 30.2
    order = [kinds.index(k) for k in ("decay_standstill", "decay_reinitialised", "decay_released")]
    assert order == sorted(order)
    reinit = next(e for e in events if e["event"] == "decay_reinitialised")
    released = next(e for e in events if e["event"] == "decay_released")
    assert 49.9 < reinit["at"] - T0 < 50.2
    assert released["at"] > reinit["at"] and released["confirmed"] == 20
    assert kinds.count("decay_entered") == 1 and kinds.count("decay_released") == 1
    # no position at all on the standard output from the decay to its release; positions after it
    t_in, t_out = entered["at"], released["at"]
    assert not [t for t, _ in sent if t_in <= t < t_out]
    after = [decode_output(p) for t, p in sent if t >= t_out]
    assert len(after) > 100
    assert pipe.metrics(dgrams[-1][0])["vital"]["decay"]["releases"] == 1


def test_decay_stays_latched_without_a_ground_truth(track):
    dgrams = _decay_world(track)  # standstill from 40 s, but no GROUND TRUTH: never released
    pipe = Pipeline(track, ListenerConfig(link=LinkConfig(extended=True)))
    sent, events = _drive(pipe, dgrams)
    entered = next(e for e in events if e["event"] == "decay_entered")
    assert not any(e["event"] == "decay_released" for e in events)
    assert any(e["event"] == "decay_standstill" for e in events)
    # the extended output keeps going while latched, and never says anything but LOST
    late = [decode_output_any(p) for t, p in sent if t > entered["at"]]
    assert len(late) > 1000 and {m.status for m in late} == {3}
    # while the filter itself is NOMINAL again at rest
    assert pipe.last_estimate.status.name == "NOMINAL"


def test_a_fault_outlasting_the_budget_latches_decay(track):
    """GNSS is not a decay reason by default; declared here, its time-out outlasting a 2 s budget latches."""
    dgrams = _no_stop(_datagrams(_run(track, 30.0), start_seq=0))
    cut = _drop(dgrams, (GPS,), 10.0)
    cfg = ListenerConfig(vital=VitalConfig(fault_budget_s=2.0, decay_reasons="gnss_timeout"))
    pipe = Pipeline(track, cfg)
    sent, events = _drive(pipe, cut)
    last_fix = _last(dgrams, GPS, 10.0)
    deg = [e for e in _status_events(events, "degraded") if e["at"] > last_fix][0]
    entered = next(e for e in events if e["event"] == "decay_entered")
    assert entered["cause"] == "gnss_timeout for more than 2 s"
    assert entered["at"] - deg["at"] == pytest.approx(2.0, abs=1e-6)
    assert not [t for t, _ in sent if t >= entered["at"]]
    default, _ = _drive(Pipeline(track, ListenerConfig()), cut)
    assert len(default) > len(sent) + 1000  # by default a GNSS outage degrades, the output goes on


def test_supervisor_unit_sequence():
    sup = DecaySupervisor(VitalConfig(fault_budget_s=1.0, recovery_updates=2))
    assert sup.observe(2, ("imu_stuck",), 0.0) == []
    assert sup.next_timer() == 1.0
    assert [e["event"] for e in sup.observe(2, ("imu_stuck",), 1.0)] == ["decay_entered"]
    assert sup.observe(1, (), 2.0) == [] and sup.latched  # NOMINAL again does not release
    assert sup.on_update("init", 6, 1, (), 2.5)[0]["event"] == "decay_recovery_rejected"
    assert sup.on_update("odo", 0, 1, ("standstill",), 3.0)[0]["event"] == "decay_standstill"
    assert sup.on_update("odo", 0, 1, (), 3.1)[0]["event"] == "decay_recovery_reset"  # moved
    sup.on_update("odo", 0, 1, ("standstill",), 3.2)
    assert sup.on_update("init", 6, 1, ("standstill",), 3.3)[0]["event"] == "decay_reinitialised"
    assert sup.on_update("odo", 0, 1, (), 3.4) == []
    assert sup.on_update("odo", 1, 1, (), 3.5) == []  # gated: count restarts
    assert sup.confirmed == 0
    sup.on_update("gps", 0, 1, (), 3.6)
    assert sup.on_update("odo", 0, 1, (), 3.7)[0]["event"] == "decay_released"
    assert not sup.latched and sup.releases == 1


def test_module_health_rate_and_bounded_memory():
    mod = ModuleHealth("imu", 100.0, 1.0)
    for i in range(5000):
        mod.heard(i * 0.01)
    assert mod.rate(49.99) == pytest.approx(100.0, rel=0.02)
    assert mod.age(50.5) == pytest.approx(0.51)
    assert mod.rate(60.0) == 0.0
    assert len(mod._times) <= 400


@pytest.mark.parametrize(
    ("key", "value"),
    [("standard_output", "never"), ("decay_reasons", "imu_timeout,bogus"), ("recovery_updates", 0),
     ("fault_budget_s", -1.0), ("timeout_margin_s", 0.5)],
)
def test_bad_vital_configuration_names_the_key(key, value):
    with pytest.raises(ConfigError, match=f"vital.{key}"):
        config_from_dict({"vital": {key: value}})


def test_timer_rechecks_a_time_out_the_filter_does_not_show_yet(track):
    """IMU epochs 30 ms ahead of the STROBE clock's mapping of their arrival: at the arrival-based
    deadline the filter's own time-out is 30 ms away. The timer looks again every 2 ms (bounded) and
    reports it then, instead of spinning on the same deadline or waiting for the next measurement."""
    import struct

    dgrams = []
    for t, addr, p in _no_stop(_datagrams(_run(track, 30.0), start_seq=0)):
        if p[0] == IMU:
            f = list(struct.unpack("<BHBB7d", p))
            f[-1] += 0.03
            p = struct.pack("<BHBB7d", *f)
        dgrams.append((t, addr, p))
    cut = _drop(dgrams, (IMU,), 20.0)
    last = _last(dgrams, IMU, 20.0)
    pipe = Pipeline(track, ListenerConfig())
    _, events = _drive(pipe, cut, until=T0 + 22.0)
    ev = [e for e in _status_events(events, "degraded") if e["at"] > last and "imu_timeout" in e["reasons"]]
    assert ev, [e for e in events if e["at"] > last]
    delay = ev[0]["at"] - last
    timeout = pipe._timeouts["imu"]
    assert ev[0]["source"] == "timer" and pipe.vital_counters["timer_rechecks"] >= 5
    assert timeout + 0.025 <= delay <= timeout + 0.04, delay


def test_a_module_never_heard_is_not_fitted_not_failed(track):
    """No IMU at all (a car with odometer and GNSS): the filter reports imu_timeout throughout, but
    that is not a failed sensor outlasting the budget, so decay does not latch; an IMU that was heard
    and then stopped does latch it after the budget."""
    dgrams = _no_stop(_datagrams(_run(track, 30.0), start_seq=0))
    cfg = ListenerConfig(vital=VitalConfig(fault_budget_s=3.0))
    no_imu = Pipeline(track, cfg)
    sent, events = _drive(no_imu, _drop(dgrams, (IMU,), -1.0))
    assert "imu_timeout" in no_imu.last_estimate.reasons
    assert not any(e["event"] == "decay_entered" for e in events) and len(sent) > 300
    died = Pipeline(track, cfg)
    _, events = _drive(died, _drop(dgrams, (IMU,), 10.0))
    entered = [e for e in events if e["event"] == "decay_entered"]
    assert entered and entered[0]["cause"] == "imu_timeout for more than 3 s"
