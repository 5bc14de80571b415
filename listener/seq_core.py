"""The sequence buffers' policy, once: compiled kernels over explicit state arrays (sans-I/O).

:class:`listener.seqbuf.SequenceBuffer` and :class:`listener.seqbuf.StreamTable` (the listener, per
datagram and per timer) and the replay (``tools.fast_replay``: every recorded datagram in one compiled
loop, :func:`run`) run these same functions on the same state, so the two cannot drift apart. The
policy (hold time, duplicates, late items, restart probation, suspects, the gap budget, reopen,
flush, overflow, the stream table's LRU eviction) is described in :mod:`listener.seqbuf`.

The kernels are decorated with :func:`sfa.engine.njit`: ``sfa listen`` runs the copies compiled ahead
of time into the engine extension, every other process numba's JIT of the same source.

Items are not stored here: each is an int64 id the caller maps to its object. A table of ``n`` stream
slots is four arrays (:func:`new_state`):

* ``si`` (int64, ``n x`` :func:`int_width`): per slot the scalars ``S_*`` (the counters ``S_CNT`` ..
  in the order of :class:`listener.seqbuf.SeqStats`, the gauges kept live), then the held items
  (``max_pending + 1`` records of ``P_*``: number, id, the stream's in-order count when it arrived,
  whether it arrived in order, arrival number), the probation run (``probation`` pairs: 16-bit number,
  id), the suspects (``max_suspects + 1`` records of ``U_*``), the loss window (``max_backward``
  numbers, a ring, and whether each is still "lost"), the given-back numbers (oldest first).
* ``sf`` (float64, ``n x`` :func:`float_width`): the scalars ``F_*``, then each held item's deadline,
  then each suspect's.
* ``cfg`` (float64): the configuration ``K_*`` and the region offsets.
* ``tb`` (int64): the table, ``T_*``: the LRU clock, evictions, the counters of evicted streams, the
  output counts, then the list of active slots (those holding something).

The arrival-ordered timer queue of the original (a deque with lazy deletion) is the range of arrival
numbers ``[S_HEAD, S_TAIL)``: an entry is live while a held item carries its number, so the queue's
front is the held item with the lowest arrival number, and "the queue is not empty" is kept exactly.

Every call writes the ids it releases to ``out`` (``tb[T_NOUT]`` of them), the ids it drops (duplicates,
late items, dropped probation items and suspects) to ``drop`` (``tb[T_NDROP]``), and alert records to
``al`` (``tb[T_NALERT]`` rows of ``A_*``, at most ``tb[T_ALERT_CAP]``, which the caller sets); each
call from Python starts the counts from 0.
"""

from __future__ import annotations

import math

import numpy as np

from sfa.engine import njit

MOD = 65536
MASK = 65535
HALF = 32768
PERIOD_MAX_S = 10.0  #: inter-arrivals longer than this do not enter a stream's period estimate [s]
RATE_SLACK = 0.75  #: a jump is explained by the silence before it if that lasted this share of its periods

# ---------------------------------------------------------------- si: per-slot int64 scalars
S_USED = 0  #: the slot holds a stream (0/1)
S_LRU = 1  #: the table's clock at the stream's last push (or creation)
S_KID = 2  #: the caller's key number of the stream (for alerts and run)
S_GEN = 3  #: times the slot was (re)initialised
S_HAS_REF = 4
S_REF = 5  #: ext the next number is unwrapped against
S_HAS_EXP = 6
S_EXP = 7  #: ext of the next number to release
S_START = 8  #: ext of the first number released (or to be released) in this sequence
S_MAX_EXT = 9  #: highest ext accepted in this sequence
S_FLOW = 10  #: arrivals of exactly the expected number
S_LAST_EXT = 11  #: the last such arrival's ext
S_HEAD = 12  #: arrival number of the timer queue's front
S_TAIL = 13  #: next arrival number
S_NREOPEN = 14  #: given-back numbers held
S_LOST_FLOOR = 15  #: loss records below this are gone
S_APOS = 16  #: position in the table's active list, -1 when not active
S_SORDER = 17  #: next suspect insertion number
S_CNT = 18  #: 17 counters in SeqStats order
C_RECEIVED = S_CNT + 0
C_RELEASED = S_CNT + 1
C_IN_ORDER = S_CNT + 2
C_REORDERED = S_CNT + 3
C_DUPLICATES = S_CNT + 4
C_LOST = S_CNT + 5
C_LATE = S_CNT + 6
C_RESYNCS = S_CNT + 7
C_OVERFLOW = S_CNT + 8
C_PROB_DROPS = S_CNT + 9
C_PENDING = S_CNT + 10  #: held items now (the count of the held-item records)
C_PROB_HELD = S_CNT + 11  #: probation items now
C_JUMPS_HELD = S_CNT + 12
C_JUMP_DROPS = S_CNT + 13
C_GAP_LIMITED = S_CNT + 14
C_REOPENED = S_CNT + 15
C_JUMP_HELD = S_CNT + 16  #: suspects now
N_COUNTERS = 17
S_HEADER = S_CNT + N_COUNTERS
# held item record fields
P_EXT = 0
P_ID = 1
P_E0 = 2
P_IN_ORDER = 3
P_ORDER = 4  #: arrival number (-1: put back by a suspect's release, released at once)
P_W = 5
# suspect record fields
U_EXT = 0
U_ID = 1
U_E0 = 2
U_IN_ORDER = 3
U_FRONT = 4  #: the stream reached it from below
U_ORDER = 5  #: insertion number (the oldest is dropped beyond max_suspects)
U_W = 6

# ---------------------------------------------------------------- sf: per-slot float64 scalars
F_NOW = 0  #: latest time seen (now is clamped to be non-decreasing)
F_PROB_T = 1  #: arrival of the newest probation item
F_TOKENS = 2  #: gap budget left
F_TOK_T = 3  #: when the budget was last refilled
F_LAST_T = 4  #: arrival of the last in-order (or late) item
F_PERIOD = 5  #: the stream's period (NaN: unknown)
F_HEADER = 6

# ---------------------------------------------------------------- cfg
K_HOLD = 0
K_MAX_PENDING = 1
K_MAX_FORWARD = 2
K_MAX_BACKWARD = 3
K_PROBATION = 4
K_PROB_TIMEOUT = 5
K_STARTUP_HOLD = 6
K_TRUSTED_GAP = 7
K_GAP_BUDGET = 8
K_GAP_REFILL = 9
K_JUMP_TIMEOUT = 10
K_MAX_SUSPECTS = 11
K_MAX_REOPENED = 12
K_NSLOTS = 13
K_OFF_P = 14  #: region offsets in si
K_OFF_PROB = 15
K_OFF_U = 16
K_OFF_LOST = 17
K_OFF_LOSTSET = 18
K_OFF_REOPEN = 19
K_LOST_W = 20  #: the loss ring's length (max(max_backward, 1))
K_FOFF_P = 21  #: region offsets in sf
K_FOFF_U = 22
K_SIZE = 23

# ---------------------------------------------------------------- tb
T_TICK = 0
T_EVICTIONS = 1
T_NOUT = 2
T_NDROP = 3
T_NALERT = 4
T_ALERT_CAP = 5
T_NACTIVE = 6
T_NUSED = 7
T_EVICTED_KID = 8  #: key number of the stream the last table push evicted (-1: none)
T_EVICTED = 9  #: 17 counters of the evicted streams
T_ACTIVE = T_EVICTED + N_COUNTERS  #: the active slots, nslots of them

# ---------------------------------------------------------------- alerts
A_KIND = 0
A_AT = 1
A_KID = 2
A_SEQ = 3
A_EXPECTED = 4  #: -1: unknown
A_MISSING = 5  #: NaN: not given
A_WHY = 6  #: -1: not given
A_W = 7
JUMP_HELD = 0  #: "sequence_jump_held"
JUMP_DROPPED = 1  #: "sequence_jump_dropped"
GAP_RATE_LIMITED = 2  #: "sequence_gap_rate_limited"
ALERT_KINDS = ("sequence_jump_held", "sequence_jump_dropped", "sequence_gap_rate_limited")
WHY_OWN = 0
WHY_PASSED = 1
WHY_WENT_ON = 2
ALERT_WHYS = ("its number came from the stream", "passed by the stream", "the stream went on below it")


def config_vector(cfg, nslots: int) -> np.ndarray:
    """The ``cfg`` array of a SeqBufferConfig for a table of ``nslots`` slots."""
    k = np.zeros(K_SIZE)
    k[K_HOLD] = float(cfg.hold_time_s)
    k[K_MAX_PENDING] = cfg.max_pending
    k[K_MAX_FORWARD] = cfg.max_forward
    k[K_MAX_BACKWARD] = cfg.max_backward
    k[K_PROBATION] = cfg.probation
    k[K_PROB_TIMEOUT] = float(cfg.probation_timeout_s)
    k[K_STARTUP_HOLD] = 1.0 if cfg.startup_hold else 0.0
    k[K_TRUSTED_GAP] = cfg.trusted_gap
    k[K_GAP_BUDGET] = cfg.gap_budget
    k[K_GAP_REFILL] = float(cfg.gap_refill_s)
    k[K_JUMP_TIMEOUT] = float(cfg.jump_timeout_s)
    k[K_MAX_SUSPECTS] = cfg.max_suspects
    k[K_MAX_REOPENED] = cfg.max_reopened
    k[K_NSLOTS] = nslots
    lost_w = max(cfg.max_backward, 1)
    off = S_HEADER
    k[K_OFF_P] = off
    off += P_W * (cfg.max_pending + 1)
    k[K_OFF_PROB] = off
    off += 2 * cfg.probation
    k[K_OFF_U] = off
    off += U_W * (cfg.max_suspects + 1)
    k[K_OFF_LOST] = off
    off += lost_w
    k[K_OFF_LOSTSET] = off
    off += lost_w
    k[K_OFF_REOPEN] = off
    k[K_LOST_W] = lost_w
    k[K_FOFF_P] = F_HEADER
    k[K_FOFF_U] = F_HEADER + cfg.max_pending + 1
    return k


def int_width(cfg) -> int:
    return S_HEADER + P_W * (cfg.max_pending + 1) + 2 * cfg.probation + U_W * (cfg.max_suspects + 1) + (
        2 * max(cfg.max_backward, 1) + cfg.max_reopened + 1)  # fmt: skip


def float_width(cfg) -> int:
    return F_HEADER + cfg.max_pending + 1 + cfg.max_suspects + 1


def slot_capacity(cfg) -> int:
    """Most ids one slot can hold (held items, probation items, suspects) plus the one being pushed."""
    return cfg.max_pending + 1 + cfg.probation + cfg.max_suspects + 1


def new_state(cfg, nslots: int):
    """(si, sf, k, tb) of a table of ``nslots`` empty slots (none in use) for a SeqBufferConfig."""
    si = np.zeros((nslots, int_width(cfg)), dtype=np.int64)
    sf = np.zeros((nslots, float_width(cfg)))
    tb = np.zeros(T_ACTIVE + nslots, dtype=np.int64)
    tb[T_EVICTED_KID] = -1
    return si, sf, config_vector(cfg, nslots), tb


# ============================================================================ helpers


@njit(cache=True, _nrt=False)
def _reset(tb):
    """A call from Python starts with no output (the counts of ``out``, ``drop`` and ``al``)."""
    tb[T_NOUT] = 0
    tb[T_NDROP] = 0
    tb[T_NALERT] = 0


@njit(cache=True, _nrt=False)
def _emit(tb, out, iid):
    out[tb[T_NOUT]] = iid
    tb[T_NOUT] += 1


@njit(cache=True, _nrt=False)
def _dropped(tb, drop, iid):
    drop[tb[T_NDROP]] = iid
    tb[T_NDROP] += 1


@njit(cache=True, _nrt=False)
def _alert(si, tb, al, s, kind, now, ext, missing, why):
    n = tb[T_NALERT]
    if n < tb[T_ALERT_CAP]:
        al[n, A_KIND] = kind
        al[n, A_AT] = now
        al[n, A_KID] = si[s, S_KID]
        al[n, A_SEQ] = ext & MASK
        al[n, A_EXPECTED] = (si[s, S_EXP] & MASK) if si[s, S_HAS_EXP] != 0 else -1
        al[n, A_MISSING] = missing
        al[n, A_WHY] = why
        tb[T_NALERT] = n + 1


@njit(cache=True, _nrt=False)
def _rec_find(si, s, base, n, w, f_ext, ext):
    """Index of the record with ``ext`` among the n records of width w at column ``base``, or -1."""
    for j in range(n):
        if si[s, base + w * j + f_ext] == ext:
            return j
    return -1


@njit(cache=True, _nrt=False)
def _rec_remove(si, sf, s, base, fb, w, c_count, f_id, j):
    """Remove record j of the table at column ``base`` (float column ``fb``, count in ``c_count``): the
    last one takes its place; returns its id."""
    n = si[s, c_count] - 1
    iid = si[s, base + w * j + f_id]
    if j != n:
        for f in range(w):
            si[s, base + w * j + f] = si[s, base + w * n + f]
        sf[s, fb + j] = sf[s, fb + n]
    si[s, c_count] = n
    return iid


@njit(cache=True, _nrt=False)
def _p_find(si, k, s, ext):
    return _rec_find(si, s, int(k[K_OFF_P]), si[s, C_PENDING], P_W, P_EXT, ext)


@njit(cache=True, _nrt=False)
def _p_remove(si, sf, k, s, j):
    """Remove held record j (the last one takes its place); returns its id."""
    return _rec_remove(si, sf, s, int(k[K_OFF_P]), int(k[K_FOFF_P]), P_W, C_PENDING, P_ID, j)


@njit(cache=True, _nrt=False)
def _p_add(si, sf, k, s, ext, iid, deadline, e0, in_order, order):
    base = int(k[K_OFF_P])
    n = si[s, C_PENDING]
    r = base + P_W * n
    si[s, r + P_EXT] = ext
    si[s, r + P_ID] = iid
    si[s, r + P_E0] = e0
    si[s, r + P_IN_ORDER] = in_order
    si[s, r + P_ORDER] = order
    sf[s, int(k[K_FOFF_P]) + n] = deadline
    si[s, C_PENDING] = n + 1


@njit(cache=True, _nrt=False)
def _p_min_ext(si, k, s):
    base = int(k[K_OFF_P])
    j_best = 0
    best = si[s, base + P_EXT]
    for j in range(1, si[s, C_PENDING]):
        v = si[s, base + P_W * j + P_EXT]
        if v < best:
            best = v
            j_best = j
    return j_best


@njit(cache=True, _nrt=False)
def _p_max_ext(si, k, s):
    base = int(k[K_OFF_P])
    best = si[s, base + P_EXT]
    for j in range(1, si[s, C_PENDING]):
        v = si[s, base + P_W * j + P_EXT]
        if v > best:
            best = v
    return best


@njit(cache=True, _nrt=False)
def _p_front(si, k, s):
    """The held record with the lowest arrival number (the timer queue's live front), or -1."""
    base = int(k[K_OFF_P])
    j_best = -1
    best = 0
    for j in range(si[s, C_PENDING]):
        o = si[s, base + P_W * j + P_ORDER]
        if o >= 0 and (j_best < 0 or o < best):
            best = o
            j_best = j
    return j_best


@njit(cache=True, _nrt=False)
def _u_find(si, k, s, ext):
    return _rec_find(si, s, int(k[K_OFF_U]), si[s, C_JUMP_HELD], U_W, U_EXT, ext)


@njit(cache=True, _nrt=False)
def _u_remove(si, sf, k, s, j):
    """Remove suspect record j (the last one takes its place); returns its id."""
    return _rec_remove(si, sf, s, int(k[K_OFF_U]), int(k[K_FOFF_U]), U_W, C_JUMP_HELD, U_ID, j)


@njit(cache=True, _nrt=False)
def _u_next(si, k, s, after, first):
    """The suspect with the lowest ext above ``after`` (any, when ``first``), or -1: ascending walks
    over the suspects that tolerate removals on the way, as the original's ``sorted()`` snapshot."""
    base = int(k[K_OFF_U])
    j_best = -1
    best = 0
    for j in range(si[s, C_JUMP_HELD]):
        v = si[s, base + U_W * j + U_EXT]
        if (first or v > after) and (j_best < 0 or v < best):
            best = v
            j_best = j
    return j_best


@njit(cache=True, _nrt=False)
def _lost_has(si, k, s, ext):
    if k[K_MAX_BACKWARD] == 0.0 or ext < si[s, S_LOST_FLOOR]:
        return False
    w = int(k[K_LOST_W])
    r = ext % w
    return si[s, int(k[K_OFF_LOST]) + r] == ext and si[s, int(k[K_OFF_LOSTSET]) + r] != 0


@njit(cache=True, _nrt=False)
def _lost_discard(si, k, s, ext):
    if _lost_has(si, k, s, ext):
        si[s, int(k[K_OFF_LOSTSET]) + ext % int(k[K_LOST_W])] = 0


@njit(cache=True, _nrt=False)
def _lost_clear(si, k, s):
    w = int(k[K_LOST_W])
    base = int(k[K_OFF_LOST])
    sb = int(k[K_OFF_LOSTSET])
    for r in range(w):
        si[s, base + r] = -1
        si[s, sb + r] = 0
    si[s, S_LOST_FLOOR] = 0


@njit(cache=True, _nrt=False)
def _declare_lost(si, k, s, first, end):
    """Numbers ``first .. end - 1`` are lost; keep the last max_backward of them (late vs duplicate)."""
    si[s, C_LOST] += end - first
    keep = int(k[K_MAX_BACKWARD])
    if keep == 0:
        return
    w = int(k[K_LOST_W])
    base = int(k[K_OFF_LOST])
    sb = int(k[K_OFF_LOSTSET])
    for e in range(max(first, end - keep), end):
        si[s, base + e % w] = e
        si[s, sb + e % w] = 1
    si[s, S_LOST_FLOOR] = end - keep


@njit(cache=True, _nrt=False)
def _reopen_find(si, k, s, ext):
    base = int(k[K_OFF_REOPEN])
    for j in range(si[s, S_NREOPEN]):
        if si[s, base + j] == ext:
            return j
    return -1


@njit(cache=True, _nrt=False)
def _reopen_remove(si, k, s, j):
    base = int(k[K_OFF_REOPEN])
    n = si[s, S_NREOPEN]
    for i in range(j, n - 1):
        si[s, base + i] = si[s, base + i + 1]
    si[s, S_NREOPEN] = n - 1


@njit(cache=True, _nrt=False)
def _set_active(si, tb, s):
    """Keep the table's active list (slots holding something) in step with slot s."""
    holds = si[s, C_PENDING] + si[s, C_PROB_HELD] + si[s, C_JUMP_HELD] > 0
    pos = si[s, S_APOS]
    if holds and pos < 0:
        n = tb[T_NACTIVE]
        tb[T_ACTIVE + n] = s
        si[s, S_APOS] = n
        tb[T_NACTIVE] = n + 1
    elif not holds and pos >= 0:
        n = tb[T_NACTIVE] - 1
        last = tb[T_ACTIVE + n]
        tb[T_ACTIVE + pos] = last
        si[last, S_APOS] = pos
        si[s, S_APOS] = -1
        tb[T_NACTIVE] = n


# ============================================================================ one stream


@njit(cache=True, _nrt=False)
def init_slot(si, sf, k, tb, s):
    """Slot s holds a new, empty stream."""
    gen = si[s, S_GEN] + 1
    for i in range(si.shape[1]):
        si[s, i] = 0
    for i in range(sf.shape[1]):
        sf[s, i] = 0.0
    si[s, S_GEN] = gen
    si[s, S_USED] = 1
    si[s, S_KID] = s
    si[s, S_LAST_EXT] = -1
    si[s, S_APOS] = -1
    _lost_clear(si, k, s)
    sf[s, F_NOW] = -math.inf
    sf[s, F_TOKENS] = k[K_GAP_BUDGET]
    sf[s, F_TOK_T] = -math.inf
    sf[s, F_LAST_T] = -math.inf
    sf[s, F_PERIOD] = math.nan
    tb[T_NUSED] += 1


@njit(cache=True, _nrt=False)
def _release_run(si, sf, k, tb, out, s):
    """Release the held items contiguous with the expected number."""
    e = si[s, S_EXP]
    n = 0
    while si[s, C_PENDING] > 0:
        j = _p_find(si, k, s, e)
        if j < 0:
            break
        _emit(tb, out, _p_remove(si, sf, k, s, j))
        e += 1
        n += 1
    si[s, C_RELEASED] += n
    si[s, S_EXP] = e
    si[s, S_REF] = e


@njit(cache=True, _nrt=False)
def _release_through(si, sf, k, tb, out, s, last):
    """Release every held item up to ``last`` (declaring the gaps lost), then the contiguous run."""
    base = int(k[K_OFF_P])
    if si[s, S_HAS_EXP] == 0:  # end of the startup hold: the lowest number seen is the start
        lo = si[s, base + P_W * _p_min_ext(si, k, s) + P_EXT]
        si[s, S_HAS_EXP] = 1
        si[s, S_EXP] = lo
        si[s, S_REF] = lo
        si[s, S_START] = lo
    e = si[s, S_EXP]
    while si[s, C_PENDING] > 0:
        j = _p_min_ext(si, k, s)
        kx = si[s, base + P_W * j + P_EXT]
        if kx > last:
            break
        if kx > e:
            _declare_lost(si, k, s, e, kx)
        _emit(tb, out, _p_remove(si, sf, k, s, j))
        si[s, C_RELEASED] += 1
        e = kx + 1
    si[s, S_EXP] = e
    si[s, S_REF] = e
    _release_run(si, sf, k, tb, out, s)


@njit(cache=True, _nrt=False)
def _release_all(si, sf, k, tb, out, s):
    if si[s, C_PENDING] > 0:
        _release_through(si, sf, k, tb, out, s, _p_max_ext(si, k, s))
    si[s, S_HEAD] = si[s, S_TAIL]  # the timer queue is cleared
    si[s, S_NREOPEN] = 0


@njit(cache=True, _nrt=False)
def _hold_item(si, sf, k, tb, out, s, ext, iid, now):
    in_order = ext > si[s, S_MAX_EXT]
    if in_order:
        si[s, S_MAX_EXT] = ext
        si[s, C_IN_ORDER] += 1
    else:
        si[s, C_REORDERED] += 1
    order = si[s, S_TAIL]
    si[s, S_TAIL] = order + 1
    _p_add(si, sf, k, s, ext, iid, now + k[K_HOLD], si[s, S_FLOW], 1 if in_order else 0, order)
    if si[s, S_HAS_EXP] == 0 and ext < si[s, S_START]:
        si[s, S_START] = ext
    base = int(k[K_OFF_P])
    while si[s, C_PENDING] > int(k[K_MAX_PENDING]):
        si[s, C_OVERFLOW] += 1
        lo = si[s, base + P_W * _p_min_ext(si, k, s) + P_EXT]
        _release_through(si, sf, k, tb, out, s, lo)


@njit(cache=True, _nrt=False)
def _confirmed(si, k, s, ext):
    """``probation - 1`` more items are held within ``trusted_gap`` above ``ext``."""
    need = int(k[K_PROBATION]) - 1
    if need <= 0:
        return True
    top = ext + int(k[K_TRUSTED_GAP]) + 1
    base = int(k[K_OFF_P])
    n = 0
    for j in range(si[s, C_PENDING]):
        v = si[s, base + P_W * j + P_EXT]
        if ext < v and v <= top:
            n += 1
            if n >= need:
                return True
    return False


@njit(cache=True, _nrt=False)
def _trusted(si, sf, k, tb, al, s, ext, e0, now, limited_alert, has_arrived, arrived):
    """Whether the hold timer may release ``ext`` (declaring the gap below it lost)."""
    if si[s, S_HAS_EXP] == 0 or ext <= si[s, S_EXP]:  # the startup hold; or nothing is skipped
        return True
    expected = si[s, S_EXP]
    small = ext - expected <= int(k[K_TRUSTED_GAP])
    flow = si[s, S_FLOW]
    # a large jump is confirmed only while the stream stayed silent below it
    if (small or flow == e0) and _confirmed(si, k, s, ext):
        return True
    if flow != e0:
        return False  # the stream went on in order below it since it arrived
    period = sf[s, F_PERIOD]
    if has_arrived and not math.isnan(period):
        # the numbers missing are what the sender's rate explains for the silence before it
        if arrived - sf[s, F_LAST_T] >= RATE_SLACK * float(ext - expected + 1) * period:
            return True
    if not small:
        return False
    tokens = min(k[K_GAP_BUDGET], sf[s, F_TOKENS] + (now - sf[s, F_TOK_T]) / k[K_GAP_REFILL])
    sf[s, F_TOK_T] = now
    if tokens >= 1.0:
        sf[s, F_TOKENS] = tokens - 1.0
        return True
    sf[s, F_TOKENS] = tokens
    if limited_alert:
        si[s, C_GAP_LIMITED] += 1
        _alert(si, tb, al, s, GAP_RATE_LIMITED, now, ext, float(ext - expected), -1)
    return False


@njit(cache=True, _nrt=False)
def _reset_max(si, k, s):
    """The highest accepted number without the suspects (so the in-order count stays honest)."""
    top = (si[s, S_EXP] if si[s, S_HAS_EXP] != 0 else 0) - 1
    if si[s, C_PENDING] > 0:
        top = max(top, _p_max_ext(si, k, s))
    if top < si[s, S_MAX_EXT]:
        si[s, S_MAX_EXT] = top


@njit(cache=True, _nrt=False)
def _suspect(si, sf, k, tb, drop, al, s, j, now):
    """Take held record j out of the release path until it is confirmed or its time-out."""
    base = int(k[K_OFF_P])
    ext = si[s, base + P_W * j + P_EXT]
    e0 = si[s, base + P_W * j + P_E0]
    in_order = si[s, base + P_W * j + P_IN_ORDER]
    iid = _p_remove(si, sf, k, s, j)
    if in_order != 0:
        si[s, C_IN_ORDER] -= 1
    else:
        si[s, C_REORDERED] -= 1
    si[s, C_JUMPS_HELD] += 1
    ub = int(k[K_OFF_U])
    n = si[s, C_JUMP_HELD]
    r = ub + U_W * n
    si[s, r + U_EXT] = ext
    si[s, r + U_ID] = iid
    si[s, r + U_E0] = e0
    si[s, r + U_IN_ORDER] = in_order
    si[s, r + U_FRONT] = 0
    si[s, r + U_ORDER] = si[s, S_SORDER]
    si[s, S_SORDER] += 1
    sf[s, int(k[K_FOFF_U]) + n] = now + k[K_JUMP_TIMEOUT]
    si[s, C_JUMP_HELD] = n + 1
    missing = ext - si[s, S_EXP] if si[s, S_HAS_EXP] != 0 else 0
    _alert(si, tb, al, s, JUMP_HELD, now, ext, float(missing), -1)
    while si[s, C_JUMP_HELD] > int(k[K_MAX_SUSPECTS]):
        oldest = 0
        for i in range(1, si[s, C_JUMP_HELD]):
            if si[s, ub + U_W * i + U_ORDER] < si[s, ub + U_W * oldest + U_ORDER]:
                oldest = i
        _dropped(tb, drop, _u_remove(si, sf, k, s, oldest))
        si[s, C_JUMP_DROPS] += 1
    _reset_max(si, k, s)


@njit(cache=True, _nrt=False)
def _unsuspect(si, sf, k, tb, out, s, j):
    """Release suspect record j now (confirmed, or its stream stayed silent below it)."""
    ub = int(k[K_OFF_U])
    ext = si[s, ub + U_W * j + U_EXT]
    in_order = si[s, ub + U_W * j + U_IN_ORDER]
    iid = _u_remove(si, sf, k, s, j)
    if in_order != 0 or ext > si[s, S_MAX_EXT]:
        si[s, C_IN_ORDER] += 1
    else:
        si[s, C_REORDERED] += 1
    if ext > si[s, S_MAX_EXT]:
        si[s, S_MAX_EXT] = ext
    _p_add(si, sf, k, s, ext, iid, 0.0, 0, 0, -1)  # no timer: released now
    _release_through(si, sf, k, tb, out, s, ext)


@njit(cache=True, _nrt=False)
def _confirm(si, sf, k, tb, out, s, ext):
    """A newly held ``ext`` may confirm suspects below it."""
    tg = int(k[K_TRUSTED_GAP])
    span = tg + 1
    ub = int(k[K_OFF_U])
    after = 0
    first = True
    while True:
        j = _u_next(si, k, s, after, first)
        if j < 0:
            break
        sx = si[s, ub + U_W * j + U_EXT]
        first = False
        after = sx
        if not (sx < ext and ext <= sx + span) or not _confirmed(si, k, s, sx):
            continue
        if si[s, S_HAS_EXP] == 0 or sx - si[s, S_EXP] <= tg or si[s, S_FLOW] == si[s, ub + U_W * j + U_E0]:
            _unsuspect(si, sf, k, tb, out, s, j)


@njit(cache=True, _nrt=False)
def _expire_suspects(si, sf, k, tb, out, drop, al, s, now):
    ub = int(k[K_OFF_U])
    fu = int(k[K_FOFF_U])
    after = 0
    first = True
    while True:
        j = _u_next(si, k, s, after, first)
        if j < 0:
            break
        sx = si[s, ub + U_W * j + U_EXT]
        first = False
        after = sx
        deadline = sf[s, fu + j]
        e0 = si[s, ub + U_W * j + U_E0]
        has_exp = si[s, S_HAS_EXP] != 0
        expected = si[s, S_EXP]
        flow = si[s, S_FLOW]
        if has_exp and sx == expected and flow != e0:
            # the stream reached it from below: its number's own datagram, if the suspect was a
            # forgery, comes next (push drops the suspect then); nothing for jump_timeout_s: keep it
            if si[s, ub + U_W * j + U_FRONT] == 0:
                si[s, ub + U_W * j + U_FRONT] = 1
                sf[s, fu + j] = now + k[K_JUMP_TIMEOUT]
            elif deadline <= now:
                _unsuspect(si, sf, k, tb, out, s, j)
        elif has_exp and sx < expected:  # the stream's in-order numbers passed it
            _dropped(tb, drop, _u_remove(si, sf, k, s, j))
            si[s, C_JUMP_DROPS] += 1
            _alert(si, tb, al, s, JUMP_DROPPED, now, sx, math.nan, WHY_PASSED)
        elif deadline <= now:
            if flow == e0:  # silent below it since it arrived: a last item after a loss
                _unsuspect(si, sf, k, tb, out, s, j)
            else:
                _dropped(tb, drop, _u_remove(si, sf, k, s, j))
                si[s, C_JUMP_DROPS] += 1
                _alert(si, tb, al, s, JUMP_DROPPED, now, sx, math.nan, WHY_WENT_ON)
        elif _trusted(si, sf, k, tb, al, s, sx, e0, now, False, False, 0.0):  # e.g. the gap shrank
            _unsuspect(si, sf, k, tb, out, s, j)


@njit(cache=True, _nrt=False)
def _expire(si, sf, k, tb, out, drop, al, s, now):
    base = int(k[K_OFF_P])
    fb = int(k[K_FOFF_P])
    while si[s, S_HEAD] < si[s, S_TAIL]:
        j = _p_front(si, k, s)
        if j < 0:
            si[s, S_HEAD] = si[s, S_TAIL]  # only released entries were left
            break
        order = si[s, base + P_W * j + P_ORDER]
        si[s, S_HEAD] = order
        deadline = sf[s, fb + j]
        if deadline > now:
            break
        si[s, S_HEAD] = order + 1
        ext = si[s, base + P_W * j + P_EXT]
        e0 = si[s, base + P_W * j + P_E0]
        if _trusted(si, sf, k, tb, al, s, ext, e0, now, True, True, deadline - k[K_HOLD]):
            _release_through(si, sf, k, tb, out, s, ext)
        else:
            _suspect(si, sf, k, tb, drop, al, s, _p_find(si, k, s, ext), now)
    if si[s, C_JUMP_HELD] > 0:
        _expire_suspects(si, sf, k, tb, out, drop, al, s, now)
    if si[s, C_PROB_HELD] > 0 and now >= sf[s, F_PROB_T] + k[K_PROB_TIMEOUT]:
        _drop_probation(si, k, tb, drop, s)


@njit(cache=True, _nrt=False)
def _drop_probation(si, k, tb, drop, s):
    pb = int(k[K_OFF_PROB])
    n = si[s, C_PROB_HELD]
    for i in range(n):
        _dropped(tb, drop, si[s, pb + 2 * i + 1])
    si[s, C_PROB_DROPS] += n
    si[s, C_PROB_HELD] = 0


@njit(cache=True, _nrt=False)
def _resync(si, sf, k, tb, out, drop, s):
    """Accept the probation run as the new sequence: flush the old one, then release the run."""
    _release_all(si, sf, k, tb, out, s)
    pb = int(k[K_OFF_PROB])
    top = max(si[s, S_MAX_EXT], si[s, S_REF] if si[s, S_HAS_REF] != 0 else 0)
    base = ((top >> 16) + 2) << 16  # a fresh cycle: the old numbers can never be mistaken for new ones
    first = base + si[s, pb]
    n = si[s, C_PROB_HELD]
    for i in range(n):
        _emit(tb, out, si[s, pb + 2 * i + 1])
    si[s, C_PROB_HELD] = 0
    si[s, C_RELEASED] += n
    si[s, C_IN_ORDER] += n
    si[s, S_START] = first
    si[s, S_HAS_EXP] = 1
    si[s, S_HAS_REF] = 1
    si[s, S_EXP] = first + n
    si[s, S_REF] = first + n
    si[s, S_MAX_EXT] = first + n - 1
    _lost_clear(si, k, s)
    si[s, S_NREOPEN] = 0
    nu = si[s, C_JUMP_HELD]
    if nu > 0:
        ub = int(k[K_OFF_U])
        for i in range(nu):
            _dropped(tb, drop, si[s, ub + U_W * i + U_ID])
        si[s, C_JUMP_DROPS] += nu
        si[s, C_JUMP_HELD] = 0
    si[s, C_RESYNCS] += 1


@njit(cache=True, _nrt=False)
def _probation(si, sf, k, tb, out, drop, s, seq, iid, now):
    pb = int(k[K_OFF_PROB])
    n = si[s, C_PROB_HELD]
    if n > 0 and seq == ((si[s, pb + 2 * (n - 1)] + 1) & MASK):
        pass
    elif n > 0 and _in_probation(si, pb, s, n, seq):
        si[s, C_DUPLICATES] += 1
        _dropped(tb, drop, iid)
        return
    else:
        _drop_probation(si, k, tb, drop, s)
        n = 0
    si[s, pb + 2 * n] = seq
    si[s, pb + 2 * n + 1] = iid
    si[s, C_PROB_HELD] = n + 1
    sf[s, F_PROB_T] = now
    if n + 1 >= int(k[K_PROBATION]):
        _resync(si, sf, k, tb, out, drop, s)


@njit(cache=True, _nrt=False)
def _in_probation(si, pb, s, n, seq):
    for i in range(n):
        if si[s, pb + 2 * i] == seq:
            return True
    return False


@njit(cache=True, _nrt=False)
def _first(si, sf, k, tb, out, s, seq, iid, now):
    ext = MOD + seq  # any base works; one cycle up keeps "behind the first" non-negative
    si[s, S_HAS_REF] = 1
    si[s, S_REF] = ext
    si[s, S_START] = ext
    si[s, S_MAX_EXT] = ext - 1
    if k[K_STARTUP_HOLD] != 0.0:
        _hold_item(si, sf, k, tb, out, s, ext, iid, now)
    else:
        si[s, S_HAS_EXP] = 1
        si[s, S_EXP] = ext + 1
        si[s, S_REF] = ext + 1
        si[s, S_MAX_EXT] = ext
        si[s, C_IN_ORDER] += 1
        si[s, C_RELEASED] += 1
        _emit(tb, out, iid)


@njit(cache=True, _nrt=False)
def _push(si, sf, k, tb, out, drop, al, s, seq, iid, now):
    if now > sf[s, F_NOW]:
        sf[s, F_NOW] = now
    else:
        now = sf[s, F_NOW]
    if si[s, S_HEAD] < si[s, S_TAIL] or si[s, C_PROB_HELD] > 0 or si[s, C_JUMP_HELD] > 0:
        _expire(si, sf, k, tb, out, drop, al, s, now)
    si[s, C_RECEIVED] += 1
    if si[s, S_HAS_REF] == 0:
        _first(si, sf, k, tb, out, s, seq, iid, now)
        if si[s, S_HEAD] < si[s, S_TAIL]:
            _expire(si, sf, k, tb, out, drop, al, s, now)  # hold_time_s == 0 releases at once
        return
    ref = si[s, S_REF]
    d = ((seq - ref + HALF) & MASK) - HALF
    ext = ref + d
    if si[s, C_JUMP_HELD] > 0 and si[s, S_HAS_EXP] != 0:
        expected = si[s, S_EXP]
        j = _u_find(si, k, s, expected)
        if j >= 0:  # the stream reached a suspect from below: the next datagram says which it was
            if ext == expected:  # its number's own datagram: the suspect was the forgery
                _dropped(tb, drop, _u_remove(si, sf, k, s, j))
                si[s, C_JUMP_DROPS] += 1
                _alert(si, tb, al, s, JUMP_DROPPED, now, ext, math.nan, WHY_OWN)
            elif ext > expected:  # the stream went past it: it was the real one (a reordered item)
                _unsuspect(si, sf, k, tb, out, s, j)
                d = ext - si[s, S_REF]
    if d == 0 and si[s, S_HAS_EXP] != 0:  # the next expected number: the common case
        si[s, S_FLOW] += 1
        if ext == si[s, S_LAST_EXT] + 1:
            dt = now - sf[s, F_LAST_T]
            if dt < PERIOD_MAX_S:
                p = sf[s, F_PERIOD]
                sf[s, F_PERIOD] = dt if math.isnan(p) else p + 0.125 * (dt - p)
        si[s, S_LAST_EXT] = ext
        sf[s, F_LAST_T] = now
        if ext > si[s, S_MAX_EXT]:
            si[s, S_MAX_EXT] = ext
            si[s, C_IN_ORDER] += 1
        else:
            si[s, C_REORDERED] += 1
        _emit(tb, out, iid)
        si[s, C_RELEASED] += 1
        si[s, S_EXP] = ext + 1
        si[s, S_REF] = ext + 1
        if si[s, C_PENDING] > 0:
            _release_run(si, sf, k, tb, out, s)
        return
    maxf = int(k[K_MAX_FORWARD])
    maxb = int(k[K_MAX_BACKWARD])
    if si[s, S_HAS_EXP] == 0:  # startup hold: the start of the stream is not known yet
        if -maxb <= d and d <= maxf:
            if _p_find(si, k, s, ext) >= 0:
                si[s, C_DUPLICATES] += 1
                _dropped(tb, drop, iid)
            else:
                _hold_item(si, sf, k, tb, out, s, ext, iid, now)
        else:
            _probation(si, sf, k, tb, out, drop, s, seq, iid, now)
    elif 0 < d and d <= maxf:
        if _p_find(si, k, s, ext) >= 0 or _u_find(si, k, s, ext) >= 0:
            si[s, C_DUPLICATES] += 1
            _dropped(tb, drop, iid)
        else:
            _hold_item(si, sf, k, tb, out, s, ext, iid, now)
            if si[s, C_JUMP_HELD] > 0:
                _confirm(si, sf, k, tb, out, s, ext)
    elif -maxb <= d and d < 0:
        j = _reopen_find(si, k, s, ext) if si[s, S_NREOPEN] > 0 else -1
        if j >= 0:  # given back after a content rejection: a second chance
            _reopen_remove(si, k, s, j)
            si[s, C_REOPENED] += 1
            si[s, C_REORDERED] += 1
            si[s, C_RELEASED] += 1
            _emit(tb, out, iid)
        elif ext < si[s, S_START] or _lost_has(si, k, s, ext):
            _lost_discard(si, k, s, ext)  # a second copy of a late item is a duplicate
            si[s, C_LATE] += 1
            si[s, S_FLOW] += 1  # the stream is alive below the release point: no jump is silent
            sf[s, F_LAST_T] = now
            _dropped(tb, drop, iid)
        else:
            si[s, C_DUPLICATES] += 1
            _dropped(tb, drop, iid)
    else:
        _probation(si, sf, k, tb, out, drop, s, seq, iid, now)
    if si[s, S_HEAD] < si[s, S_TAIL]:
        _expire(si, sf, k, tb, out, drop, al, s, now)  # hold_time_s == 0 releases at once


@njit(cache=True, _nrt=False)
def push(si, sf, k, tb, out, drop, al, s, seq, iid, now):
    """Accept item ``iid`` with 16-bit number ``seq`` at ``now`` into slot s; its releases to ``out``.
    Returns 0, or -1 (nothing done) when ``now`` is NaN."""
    _reset(tb)
    if now != now:
        return -1
    _push(si, sf, k, tb, out, drop, al, s, seq, iid, now)
    _set_active(si, tb, s)
    return 0


@njit(cache=True, _nrt=False)
def poll(si, sf, k, tb, out, drop, al, s, now):
    """Release what the passage of time makes due in slot s. -1 (nothing done) when ``now`` is NaN."""
    _reset(tb)
    return _poll(si, sf, k, tb, out, drop, al, s, now)


@njit(cache=True, _nrt=False)
def _poll(si, sf, k, tb, out, drop, al, s, now):
    if now != now:
        return -1
    if now > sf[s, F_NOW]:
        sf[s, F_NOW] = now
    _expire(si, sf, k, tb, out, drop, al, s, sf[s, F_NOW])
    _set_active(si, tb, s)
    return 0


@njit(cache=True, _nrt=False)
def next_deadline(si, sf, k, s):
    """The earliest ``now`` at which :func:`poll` has something to do in slot s, or NaN (nothing held)."""
    deadline = math.nan
    if si[s, S_HEAD] < si[s, S_TAIL]:
        j = _p_front(si, k, s)
        if j < 0:
            si[s, S_HEAD] = si[s, S_TAIL]
        else:
            si[s, S_HEAD] = si[s, int(k[K_OFF_P]) + P_W * j + P_ORDER]
            deadline = sf[s, int(k[K_FOFF_P]) + j]
    if si[s, C_PROB_HELD] > 0:
        pd = sf[s, F_PROB_T] + k[K_PROB_TIMEOUT]
        deadline = pd if math.isnan(deadline) else min(deadline, pd)
    fu = int(k[K_FOFF_U])
    for j in range(si[s, C_JUMP_HELD]):
        v = sf[s, fu + j]
        if math.isnan(deadline) or v < deadline:
            deadline = v
    return deadline


@njit(cache=True, _nrt=False)
def reopen(si, k, s, seq):
    """Give back the number ``seq`` of a released item the caller rejected for its content; True if
    given back (a later item with that number is then accepted, not a duplicate)."""
    if si[s, S_HAS_REF] == 0 or si[s, S_HAS_EXP] == 0 or k[K_MAX_REOPENED] == 0.0:
        return False
    ref = si[s, S_REF]
    d = ((seq - ref + HALF) & MASK) - HALF
    ext = ref + d
    if not (-int(k[K_MAX_BACKWARD]) <= d and d < 0) or ext < si[s, S_START]:
        return False
    if _reopen_find(si, k, s, ext) >= 0:
        return False
    base = int(k[K_OFF_REOPEN])
    n = si[s, S_NREOPEN]
    si[s, base + n] = ext
    si[s, S_NREOPEN] = n + 1
    if n + 1 > int(k[K_MAX_REOPENED]):
        _reopen_remove(si, k, s, 0)
    return True


@njit(cache=True, _nrt=False)
def _flush(si, sf, k, tb, out, drop, s):
    ub = int(k[K_OFF_U])
    while si[s, C_JUMP_HELD] > 0:  # as at their time-out: kept if the stream stayed silent below
        j = _u_next(si, k, s, 0, True)
        ext = si[s, ub + U_W * j + U_EXT]
        e0 = si[s, ub + U_W * j + U_E0]
        in_order = si[s, ub + U_W * j + U_IN_ORDER]
        iid = _u_remove(si, sf, k, s, j)
        if si[s, S_FLOW] == e0 and (si[s, S_HAS_EXP] == 0 or ext >= si[s, S_EXP]):
            _p_add(si, sf, k, s, ext, iid, 0.0, 0, 0, -1)
            if in_order != 0 or ext > si[s, S_MAX_EXT]:
                si[s, C_IN_ORDER] += 1
            else:
                si[s, C_REORDERED] += 1
            if ext > si[s, S_MAX_EXT]:
                si[s, S_MAX_EXT] = ext
        else:
            si[s, C_JUMP_DROPS] += 1
            _dropped(tb, drop, iid)
    _release_all(si, sf, k, tb, out, s)
    _drop_probation(si, k, tb, drop, s)
    _set_active(si, tb, s)


@njit(cache=True, _nrt=False)
def flush(si, sf, k, tb, out, drop, s):
    """Release everything held in slot s, in order (gaps declared lost); drop the probation items."""
    _reset(tb)
    _flush(si, sf, k, tb, out, drop, s)


@njit(cache=True, _nrt=False)
def footprint(si, k, s):
    """Entries slot s stores now: held items and their timer entries, loss records, probation items,
    suspects, given-back numbers."""
    n = si[s, C_PENDING] + (si[s, S_TAIL] - si[s, S_HEAD]) + si[s, C_PROB_HELD] + si[s, C_JUMP_HELD]
    n += si[s, S_NREOPEN]
    if k[K_MAX_BACKWARD] != 0.0:
        base = int(k[K_OFF_LOST])
        for r in range(int(k[K_LOST_W])):
            v = si[s, base + r]
            if v >= 0 and v >= si[s, S_LOST_FLOOR]:
                n += 1
    return n


# ============================================================================ the table


@njit(cache=True, _nrt=False)
def _new_stream(si, sf, k, tb, out, drop, kid):
    """A slot for a new stream (the least recently used one flushed and evicted when all are taken)."""
    nslots = si.shape[0]
    tb[T_EVICTED_KID] = -1
    s = -1
    if tb[T_NUSED] < nslots:
        for i in range(nslots):
            if si[i, S_USED] == 0:
                s = i
                break
    else:
        s = 0
        for i in range(1, nslots):
            if si[i, S_LRU] < si[s, S_LRU]:
                s = i
        _flush(si, sf, k, tb, out, drop, s)
        for c in range(N_COUNTERS):
            tb[T_EVICTED + c] += si[s, S_CNT + c]
        tb[T_EVICTIONS] += 1
        tb[T_EVICTED_KID] = si[s, S_KID]
        si[s, S_USED] = 0
        tb[T_NUSED] -= 1
    init_slot(si, sf, k, tb, s)
    if kid >= 0:
        si[s, S_KID] = kid
    return s


@njit(cache=True, _nrt=False)
def table_push(si, sf, k, tb, out, drop, al, s, kid, seq, iid, now):
    """Push into slot s (-1: a new stream, key number ``kid`` or, if -1, the slot's own number, given a
    slot); the slot used, or -1
    (nothing done) when ``now`` is NaN. A new stream beyond the table's size evicts the least
    recently used one (its items flushed to ``out`` first; ``tb[T_EVICTED_KID]`` names it)."""
    _reset(tb)
    return _table_push(si, sf, k, tb, out, drop, al, s, kid, seq, iid, now)


@njit(cache=True, _nrt=False)
def _table_push(si, sf, k, tb, out, drop, al, s, kid, seq, iid, now):
    if now != now:
        return -1
    if s < 0:
        s = _new_stream(si, sf, k, tb, out, drop, kid)
    else:
        tb[T_EVICTED_KID] = -1
    tb[T_TICK] += 1
    si[s, S_LRU] = tb[T_TICK]
    _push(si, sf, k, tb, out, drop, al, s, seq, iid, now)
    _set_active(si, tb, s)
    return s


@njit(cache=True, _nrt=False)
def table_next_deadline(si, sf, k, tb):
    """The earliest deadline over all streams, or NaN."""
    best = math.nan
    for a in range(tb[T_NACTIVE]):
        d = next_deadline(si, sf, k, tb[T_ACTIVE + a])
        if not math.isnan(d) and (math.isnan(best) or d < best):
            best = d
    return best


@njit(cache=True, _nrt=False)
def table_poll(si, sf, k, tb, out, drop, al, now):
    """Release what is due in every stream (each stream's items in order, streams in the active list's
    order)."""
    _reset(tb)
    _table_poll(si, sf, k, tb, out, drop, al, now)


@njit(cache=True, _nrt=False)
def _table_poll(si, sf, k, tb, out, drop, al, now):
    a = tb[T_NACTIVE] - 1
    while a >= 0:  # (a slot leaving the list takes the last one's place: already visited)
        s = tb[T_ACTIVE + a]
        d = next_deadline(si, sf, k, s)
        if not math.isnan(d) and d <= now:
            _poll(si, sf, k, tb, out, drop, al, s, now)
        _set_active(si, tb, s)
        a -= 1


@njit(cache=True, _nrt=False)
def table_flush(si, sf, k, tb, out, drop):
    """Release everything held in every stream (for STOP and shutdown)."""
    _reset(tb)
    while tb[T_NACTIVE] > 0:
        _flush(si, sf, k, tb, out, drop, tb[T_ACTIVE + tb[T_NACTIVE] - 1])


@njit(cache=True, _nrt=False)
def run(si, sf, k, tb, out, out_t, out_b, drop, al, kid_slot, kids, seqs, ids, times, stop):
    """A recorded stream as the listener takes it live: before each datagram ``i`` (key number
    ``kids[i]``, 16-bit number ``seqs[i]``, id ``ids[i]``, arrival ``times[i]``), :func:`table_poll` at
    every deadline due by its arrival (the listener's timer fires at :func:`table_next_deadline`), then
    :func:`table_push` it; ``kid_slot`` maps key numbers to slots (-1: none) and is kept up to date.
    Stops after pushing datagram ``stop`` (-1: none). Each release's time goes to ``out_t`` and its
    number (0, 1, ... in order) to ``out_b``.

    Returns (datagrams pushed, -1 if ``stop`` was not pushed else whether its own push released it,
    releases made); -2 as the first value when an arrival time is NaN."""
    _reset(tb)
    batch = 0
    stop_released = -1
    n = kids.shape[0]
    for i in range(n):
        t = times[i]
        if t != t:
            return -2, stop_released, batch
        if tb[T_NACTIVE] > 0:
            nd = table_next_deadline(si, sf, k, tb)
            while not math.isnan(nd) and nd <= t:
                n0 = tb[T_NOUT]
                _table_poll(si, sf, k, tb, out, drop, al, nd)
                n1 = tb[T_NOUT]
                if n1 > n0:
                    for j in range(n0, n1):
                        out_t[j] = nd
                        out_b[j] = batch
                    batch += 1
                nd = table_next_deadline(si, sf, k, tb)
        kid = kids[i]
        s = kid_slot[kid]
        n0 = tb[T_NOUT]
        s = _table_push(si, sf, k, tb, out, drop, al, s, kid, seqs[i], ids[i], t)
        if tb[T_EVICTED_KID] >= 0:
            kid_slot[tb[T_EVICTED_KID]] = -1
        kid_slot[kid] = s
        n1 = tb[T_NOUT]
        if n1 > n0:
            for j in range(n0, n1):
                out_t[j] = t
                out_b[j] = batch
            batch += 1
        if i == stop:
            stop_released = 0
            for j in range(n0, n1):
                if out[j] == ids[i]:
                    stop_released = 1
            return i + 1, stop_released, batch
    return n, stop_released, batch
