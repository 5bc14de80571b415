"""The replay path of a campaign: the whole system on scripted time, in one process.

Offline-generated interface-module datagrams go through the input link's :class:`FaultCore` into the
listener's :class:`~listener.pipeline.Pipeline`; its outputs go through the output link's core to a
:class:`~listener.obcu.MockObcu` core, whose acks come back through the same link. Every component is
sans-I/O, so this is a discrete-event simulation: one heap of timed deliveries plus the components'
own timers, always advancing to the earliest. Same inputs and seeds, same trace, bit for bit.

Nothing is mocked: it is the code ``sfa listen`` and ``sfa obcu`` run, on a clock that is an argument.
"""

from __future__ import annotations

import heapq
import math
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from listener.service import _event_level
from tools.faults.config import Impairments
from tools.faults.core import FAULT_SENDER_ADDR, FaultCore
from tools.faults.errors import CampaignError

LISTENER_OUT_ADDR = ("127.0.0.1", 48002)  #: the listener's output socket, as the OBCU sees it
MAX_EVENTS_PER_PACKET = 400  #: bound on loop iterations per input datagram (guards against a stuck timer)


@dataclass
class FreshOutput:
    """One output the OBCU received with a SEQ newer than any before (a fresh estimate)."""

    arrival_s: float  #: OBCU arrival time (listener clock = capture clock) [s]
    seq: int
    epoch_s: float  #: sensor-set time of the estimate [s]
    arc_length_m: float
    interval_low_m: float
    interval_high_m: float
    status: int  #: FilterStatus code (extended output)
    reasons: tuple[str, ...]  #: the filter's reasons when the listener produced it


@dataclass
class Trace:
    """Everything a replay-path run observed."""

    start_s: float  #: time of the first datagram [s]
    end_s: float  #: time the run stopped [s]
    fresh: list[FreshOutput] = field(default_factory=list)
    obcu_received: int = 0  #: outputs received, retransmissions and duplicates included
    obcu_duplicates: int = 0
    metrics: dict[str, Any] = field(default_factory=dict)  #: pipeline metrics at the end
    link_transitions: list[tuple[float, str]] = field(default_factory=list)  #: (time from start, state)
    input_proxy: dict[str, int] = field(default_factory=dict)
    output_proxy: dict[str, int] = field(default_factory=dict)
    obcu_stats: dict[str, Any] = field(default_factory=dict)
    auth: dict[str, Any] = field(default_factory=dict)  #: authenticated input link: accepted, rejected, bad
    #: kill -9 and restart: kill_s, restart_s (from the start), last_seq_before (newest SEQ the OBCU had
    #: at the restart), first_seq_after (first SEQ it received after), lost_while_down, resumed
    restart: dict[str, Any] = field(default_factory=dict)
    stop_arrival_s: float | None = None  #: when the STOP datagram reached the listener (from the start) [s]
    stop_s: float | None = None  #: when the listener stopped (from the start) [s]
    status_reasons: list[str] = field(default_factory=list)  #: reasons of the non-nominal status events
    crash: str = ""  #: traceback of an exception, "" when none
    wall_s: float = 0.0  #: wall time of the run [s]
    events: int = 0  #: loop iterations


def run_replay_path(
    packets: list,
    track,
    listener_config,
    *,
    input_link: Impairments | None = None,
    output_link: Impairments | None = None,
    obcu_config=None,
    seed: int = 0,
    tail_s: float = 10.0,
    auth_master: bytes | None = None,
    restart: tuple[float, float] | None = None,
    work_dir: Path | None = None,
) -> Trace:
    """Run ``packets`` (``Packet(arrival_s, src_port, payload)``, sorted) through the whole system.

    ``seed`` seeds both links' cores (the output link's with ``seed + 1``). The run ends ``tail_s``
    after the last datagram (or once the listener stopped and ``tail_s`` passed). An exception in any
    component ends the run; its traceback is in ``Trace.crash`` (the campaign counts it as a crash).

    ``auth_master``: the input link is authenticated with per-module keys, as ``sfa listen`` with
    ``[auth]`` and ``sfa sim --live --auth-key-file`` do it: each module wraps its datagrams with its
    own key ``modules->listener:<KEY_ID>`` (KEY_ID from ``interface_modules.live.DEFAULT_KEY_IDS``)
    and its own epoch counter before the link; the listener side opens them with the listener's own
    :class:`listener.auth_link.LinkAuth` (anti-replay window per module id) before the pipeline.
    The listener is configured as ``sfa listen`` with ``[auth]`` is (a key file in ``work_dir``): the
    pipeline opens the input, seals its outputs, the mock OBCU opens them and seals its acks, and the
    sender table binds KEY_IDs. The attacker knows the format and the module ids, not the keys:
    forgeries from its own socket are wrapped under a random key with a real module's KEY_ID; those
    posing as a module on its stream (``forge_as``) are signed with that module's real key (a
    compromised key: the sender table must refuse a GROUND TRUTH or STOP under it). ``Trace.auth``
    then says how many were accepted, rejected (by reason), and ``bad``: accepted datagrams that are
    not an original (nor such a signed forgery), or an original accepted a second time.

    ``restart = (kill_s, down_s)``: the listener is killed (``kill -9``: no last checkpoint, nothing
    flushed) ``kill_s`` after the first datagram, and a new pipeline started ``down_s`` later from the
    checkpoint file the first one wrote once a second (in ``work_dir``, written and read back as the
    service does: ``write_atomic``, :meth:`listener.resilience.Resilience.load`), with the same
    configuration; what arrives meanwhile is lost (counted). ``Trace.restart`` has the figures.
    """
    import dataclasses
    import tempfile

    from listener import checkpoint as ckpt
    from listener.obcu import MockObcu, ObcuConfig
    from listener.pipeline import Pipeline
    from listener.service import write_atomic

    if not packets:
        raise CampaignError("replay path: no datagrams to run")
    t0 = float(packets[0].arrival_s)
    t_last = float(packets[-1].arrival_s)
    trace = Trace(start_s=t0, end_s=t0)
    wall0 = time.perf_counter()
    scratch = None
    if work_dir is None and (auth_master is not None or restart is not None):
        scratch = tempfile.TemporaryDirectory(prefix="sfa-replay-path-")
        work_dir = Path(scratch.name)
    obcu_config = obcu_config or ObcuConfig()
    signed: set[bytes] = set()  # forgeries signed with a real module key (not replays: see ``bad``)
    sign = None
    if auth_master is not None:
        from tools.faults.forge import module_signer

        key_file = work_dir / "master.key"
        key_file.write_text(auth_master.hex() + "\n")
        listener_config = dataclasses.replace(
            listener_config,
            auth=dataclasses.replace(listener_config.auth, enabled=True, key_file=str(key_file)))
        obcu_config = dataclasses.replace(obcu_config, auth_master_key=auth_master)
        module_sign = module_signer(auth_master, listener_config.auth.tag_bytes)

        def sign(payload: bytes, template: bytes) -> bytes:
            out = module_sign(payload, template)
            signed.add(out)
            return out
    # checkpoint.enabled = false: the restarted pipeline has no checkpoint to resume from
    keep = restart is not None and listener_config.checkpoint.enabled
    ck_path = work_dir / "listener-checkpoint.json" if keep else None
    if ck_path is not None:
        ck_path.unlink(missing_ok=True)
    pipe = Pipeline(track, listener_config)
    if ck_path is not None:
        pipe.resilience.enable_checkpoints(t0)
    alive = True
    warnings: dict[str, int] = {}
    auth_totals = {"accepted": 0, "rejected": {}}
    obcu = MockObcu(obcu_config, start=t0)
    in_core = FaultCore(input_link, seed, start=t0, sign=sign) if input_link is not None else None
    out_core = FaultCore(output_link, seed + 1, start=t0) if output_link is not None else None
    heap: list[tuple[float, int, str, bytes, Any]] = []
    order = 0

    def push(t: float, kind: str, data: bytes, addr: Any) -> None:
        nonlocal order
        order += 1
        heapq.heappush(heap, (t, order, kind, data, addr))

    originals: set[bytes] = set()
    accepted: set[bytes] = set()
    link_auth = pipe.auth
    key_ids: dict[int, int] = {}  # source port -> the module's KEY_ID
    if auth_master is not None:
        from interface_modules.live import DEFAULT_KEY_IDS
        from listener.auth import EpochCounter, input_seq, wrap

        counters: dict[int, EpochCounter] = {}
        trace.auth = {"accepted": 0, "bad": 0, "rejected": {}}
    for p in packets:
        payload = p.payload
        if link_auth is not None:
            port = int(p.src_port)
            kid = key_ids.get(port)
            if kid is None:  # a module without a default id (none in the shipped scenarios): 16, 17, ...
                kid = key_ids[port] = DEFAULT_KEY_IDS.get(getattr(p, "module", ""), 16 + len(key_ids))
            counter = counters.setdefault(port, EpochCounter())
            epoch = counter.epoch_for(input_seq(payload))
            payload = wrap(payload, link_auth.input_key(kid), epoch, key_id=kid)
            originals.add(payload)
        push(float(p.arrival_s), "sim", payload, ("127.0.0.1", int(p.src_port)))
    module_ids = sorted(set(key_ids.values()))

    def to_pipeline(data: bytes, addr: Any, now: float) -> None:
        if not alive:  # the listener's socket is closed: the kernel drops it
            trace.restart["lost_while_down"] = trace.restart.get("lost_while_down", 0) + 1
            return
        before = 0 if pipe.auth is None else pipe.auth.input_state.accepted
        outputs(pipe.receive(data, addr, now), now)
        if pipe.auth is not None and pipe.auth.input_state.accepted > before:
            if (data not in originals and data not in signed) or data in accepted:
                trace.auth["bad"] += 1
            accepted.add(data)
        if trace.stop_s is None and pipe.stopped:
            trace.stop_s = now - t0
        after_step()

    def after_step() -> None:
        """What the service does after each callback: log the events (warnings and status reasons kept),
        write a checkpoint the pipeline took."""
        if not alive:
            return
        note(pipe.take_events())
        if ck_path is not None:
            body = pipe.resilience.take_checkpoint()
            if body is not None:
                taken = body["taken"]  # as the service stamps it: this clock is also the "wall" one
                body["taken"] = {**taken, "wall": taken["monotonic"], "boot_id": "replay-path"}
                write_atomic(ck_path, ckpt.encode(body))

    def note(events) -> None:
        for ev in events:
            kind = ev.get("event", "")
            if kind == "status" and ev.get("status") != "nominal":
                trace.status_reasons.extend(r for r in ev.get("reasons", ()) if r not in trace.status_reasons)
            if _event_level(kind, dict(ev)) == "warning":
                warnings[kind] = warnings.get(kind, 0) + 1

    def retire(p) -> None:
        """Keep what a pipeline saw before it goes (the warnings it logged, its auth counters)."""
        note(p.take_events())
        if p.auth is not None:
            auth_totals["accepted"] += p.auth.input_state.accepted
            for k, v in p.auth.input_state.rejected.items():
                auth_totals["rejected"][k] = auth_totals["rejected"].get(k, 0) + v

    if restart is not None:
        kill_s, down_s = restart
        push(t0 + kill_s, "kill", b"", None)
        push(t0 + kill_s + down_s, "restart", b"", None)
        trace.restart = {"kill_s": kill_s, "restart_s": kill_s + down_s, "lost_while_down": 0}

    attacker_rng = np.random.default_rng([seed, 2])
    attacker_key = attacker_rng.bytes(32)

    def to_listener(emits) -> None:
        for t, data, sender in emits:
            if sender[0] == "forge":
                if link_auth is not None:  # the attacker knows the format and the module ids, not the keys
                    kid = module_ids[int(attacker_rng.integers(0, len(module_ids)))]
                    data = wrap(data, attacker_key, int(attacker_rng.integers(0, 2**32)), key_id=kid)
                push(t, "in", data, FAULT_SENDER_ADDR)
            else:
                push(t, "in", data, sender)

    def outputs(datagrams: list[bytes], now: float) -> None:
        for d in datagrams:
            if out_core is None:
                push(now, "obcu", d, LISTENER_OUT_ADDR)
            else:
                for t, data, _ in out_core.forward(d, LISTENER_OUT_ADDR, now):
                    push(t, "obcu", data, LISTENER_OUT_ADDR)

    def on_obcu(data: bytes, now: float) -> None:
        rec = obcu.receive(data, LISTENER_OUT_ADDR, now)
        if rec is None:
            return
        trace.obcu_received += 1
        rs = trace.restart
        if rs and now - t0 >= rs["restart_s"] and "first_seq_after" not in rs:
            trace.restart["first_seq_after"] = rec.seq
            trace.restart["first_after_s"] = now - t0
        if obcu.newest is rec:
            est = pipe.last_estimate
            reasons = tuple(est.reasons) if est is not None else ()
            trace.fresh.append(FreshOutput(
                now, rec.seq, rec.epoch, rec.arc_length,
                math.nan if rec.interval_low is None else rec.interval_low,
                math.nan if rec.interval_high is None else rec.interval_high,
                -1 if rec.status is None else int(rec.status), reasons,
            ))

    t_stop = t_last + tail_s
    limit = MAX_EVENTS_PER_PACKET * len(packets) + 1_000_000
    now = t0
    try:
        while trace.events < limit:
            trace.events += 1
            cands = [
                (heap[0][0] if heap else math.inf, 0),
                (_t(pipe.next_timer() if alive else None), 1),
                (_t(obcu.next_timer()), 2),
                (_t(in_core.next_timer() if in_core else None), 3),
                (_t(out_core.next_timer() if out_core else None), 4),
            ]
            t, which = min(cands)
            if t == math.inf or t > t_stop:
                break
            now = max(now, t)
            if which == 0:
                _, _, kind, data, addr = heapq.heappop(heap)
                if kind == "sim":
                    if in_core is None:
                        push(now, "in", data, addr)
                    else:
                        to_listener(in_core.forward(data, addr, now))
                elif kind == "in":
                    if alive and not pipe.stopped and addr != FAULT_SENDER_ADDR and _is_stop(data):
                        trace.stop_arrival_s = now - t0  # a STOP from a real sender's socket
                    to_pipeline(data, addr, now)
                elif kind == "obcu":
                    on_obcu(data, now)
                elif kind == "kill":  # SIGKILL: nothing more from this process, no last checkpoint
                    alive = False
                    retire(pipe)
                elif kind == "restart":
                    newest = obcu.newest
                    trace.restart["last_seq_before"] = None if newest is None else newest.seq
                    pipe = Pipeline(track, listener_config)
                    link_auth = pipe.auth
                    alive = True
                    data = ck_path.read_bytes() if ck_path is not None and ck_path.exists() else None
                    trace.restart["resumed"] = pipe.resilience.load(data, now, wall_now=now, mono_now=now,
                                                                    boot_id="replay-path")
                    trace.restart["checkpoint_found"] = data is not None
                elif alive:  # "ack"
                    outputs(pipe.receive_ack(data, now), now)
                    after_step()
            elif which == 1:
                outputs(pipe.handle_timer(now), now)
                if trace.stop_s is None and pipe.stopped:
                    trace.stop_s = now - t0
                after_step()
            elif which == 2:
                for ack, _addr in obcu.handle_timer(now):
                    if out_core is None:
                        push(now, "ack", ack, None)
                    else:
                        for ta, data, _ in out_core.reply(ack, LISTENER_OUT_ADDR, now):
                            push(ta, "ack", data, None)
                if obcu.next_timer() is not None and obcu.next_timer() <= now:
                    break  # pragma: no cover - the mock always moves its timer forward
            elif which == 3:
                assert in_core is not None
                to_listener(in_core.handle_timer(now))
            else:
                assert out_core is not None
                for tt, data, _ in out_core.handle_timer(now):
                    push(tt, "obcu", data, LISTENER_OUT_ADDR)
        else:
            raise CampaignError(f"replay path: no end after {limit} events (a timer does not advance)")
        outputs(pipe.flush(now), now)
        while heap:
            t, _, kind, data, addr = heapq.heappop(heap)
            if kind == "obcu":
                on_obcu(data, max(now, t))
    except CampaignError:
        raise
    except Exception:  # a crash of the system under test is a result, not an error of the tool
        trace.crash = traceback.format_exc()
    trace.end_s = now
    trace.metrics = pipe.metrics()  # after a restart: the restarted process's (as live)
    if alive:
        retire(pipe)
    trace.metrics["warnings_seen"] = dict(sorted(warnings.items()))  # every warning event logged
    trace.link_transitions = [(t - t0, s) for t, s in pipe.link.transitions]
    trace.input_proxy = in_core.stats() if in_core else {}
    if link_auth is not None:
        trace.auth["accepted"] = auth_totals["accepted"]  # every process of the run
        trace.auth["rejected"] = dict(sorted(auth_totals["rejected"].items()))
        trace.auth["modules"] = {str(k): v for k, v in sorted(key_ids.items())}  # source port -> KEY_ID
        trace.auth["windows"] = sorted(link_auth.input_state.windows)  # the listener's: per KEY_ID
    trace.output_proxy = out_core.stats() if out_core else {}
    st = obcu.stats
    trace.obcu_duplicates = st.duplicates
    trace.obcu_stats = {"received": st.received, "malformed": st.malformed, "duplicates": st.duplicates,
                        "acks_sent": st.acks_sent, "acks_dropped": st.acks_dropped, "restarts": st.restarts}
    trace.wall_s = time.perf_counter() - wall0
    if scratch is not None:
        scratch.cleanup()
    return trace


def _is_stop(data: bytes) -> bool:
    from tools.faults.forge import inner_payload

    inner = inner_payload(data) if data else None
    return inner is not None and inner[0] == 10  # SensorType.STOP


def _t(value: float | None) -> float:
    return math.inf if value is None else float(value)
