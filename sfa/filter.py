"""TrackFilter: the per-message face of the track-constrained EKF, with line hypotheses at junctions.

The mathematics lives in ``sfa.kernels`` (compiled), the hypotheses and the rules that step, score,
prune and mirror them in ``sfa.bank`` (compiled); this class converts measurements into runs of the
bank's step loop, initialises the hypotheses, spawns branches at junctions (the track database) and
turns the arrays into typed results. It never reads a clock: every time comes with a measurement or
as an argument.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from sfa import engine
from sfa import kernels as K
from sfa import layout as L
from sfa.bank import STOP_AFTER, HypothesisBank, RunOutput
from sfa.batch import NV
from sfa.config import FilterConfig
from sfa.errors import FilterStateError, MeasurementTypeError
from sfa.layout import FilterStatus, Outcome, reasons_from_bits
from sfa.measurements import GpsMeas, ImuMeas, InitMeas, OdoMeas
from sfa.track_arrays import TrackArrays


@dataclass(frozen=True, slots=True)
class Update:
    """What ``TrackFilter.process`` did with one measurement."""

    kind: str  #: "imu", "odo", "gps" or "init"
    t_s: float  #: the measurement's time [s]
    outcome: Outcome  #: accepted, gated, late, invalid, ...
    nis: float | None = None  #: normalised innovation squared of the best hypothesis (odo/gps) [-]


@dataclass(frozen=True, slots=True)
class Estimate:
    """The filter's answer at ``epoch_s``."""

    epoch_s: float  #: time of the estimate [s]
    arc_length_m: float  #: arc length on ``line_id`` [m]
    speed_mps: float  #: speed in the train's forward direction [m/s]
    sigma_s_m: float  #: 1-sigma of the arc length [m]
    interval_low_m: float  #: lower bound of the arc length at ``confidence`` (under-reading side) [m]
    interval_high_m: float  #: upper bound (over-reading side) [m]
    status: FilterStatus  #: integrity status
    reasons: tuple[str, ...]  #: why the status is not NOMINAL (and informative flags)
    line_id: int | None  #: line the estimate is on
    lat_deg: float  #: WGS84 latitude of the estimate [deg]
    lon_deg: float  #: WGS84 longitude of the estimate [deg]
    sigma_v_mps: float = math.nan  #: 1-sigma of the speed [m/s]
    confidence: float = 0.95  #: two-sided confidence of the interval [probability]
    hypotheses: int = 0  #: line / direction hypotheses currently kept
    direction: int = 0  #: +1 the train's forward is increasing arc length, -1 decreasing, 0 unknown


def _track_errors() -> tuple[type[BaseException], ...]:
    errors: list[type[BaseException]] = [KeyError, LookupError, ValueError]
    try:
        from track_db.errors import BASE_ERROR

        errors.append(BASE_ERROR)
    except ImportError:  # pragma: no cover - track_db is a hard dependency of the project
        pass
    return tuple(errors)


class TrackFilter:
    """Track-constrained EKF (arc length, speed, sensor errors) with integrity and line hypotheses.

    ``process`` takes measurements in time order (late-data policy in docs/filter.md);
    ``estimate`` reports the best hypothesis. The hypotheses live in a :class:`sfa.bank.HypothesisBank`;
    ``run`` steps a run of packed measurements through the same compiled loop (the replay).
    """

    def __init__(self, track, config: FilterConfig | None = None) -> None:
        self._track = track
        self._config = config if config is not None else FilterConfig()
        if not isinstance(self._config, FilterConfig):
            raise FilterStateError(f"config must be a FilterConfig, got {type(self._config).__name__}")
        self._cfg = self._config.to_array()
        self._z = float(self._cfg[L.K_Z_INTERVAL])
        self._lines: dict[int, TrackArrays] = {}
        self._bank = HypothesisBank(self._config.max_hypotheses)
        self._bank.junction_s = self._junction_s
        self._junctions = None  # built lazily: line_id -> list of (key, s_on_line, other_line, s_other)
        self._track_errors = _track_errors()
        self._jump_candidate = math.nan  # time of the last measurement rejected as a forward time jump
        # a run of one measurement for process(): kind, time, values (sfa.batch.Packed layout), outcome
        self._kind1 = np.zeros(1, dtype=np.int64)
        self._t1 = np.zeros(1)
        self._vals1 = np.zeros((1, NV))
        self._out1 = RunOutput.none()

    # ------------------------------------------------------------------ public API
    @property
    def config(self) -> FilterConfig:
        return self._config

    @property
    def initialised(self) -> bool:
        b = self._bank
        return b.n > 0 and b.AUX[b.order[0], L.A_INIT] != 0.0

    def warm_up(self) -> None:
        """Compile (or load from cache) every kernel on a throwaway two-vertex line."""
        line = TrackArrays(0, 100.0, np.array([0.0, 100.0]), np.array([0.0, 100.0]), np.zeros(2),
                           np.zeros(2), np.zeros(2))
        b = HypothesisBank(1)
        b.place(0, line, frozenset())
        a = (b.X[0], b.PP[0], b.AUX[0], b.CNT[0], b.MEM[0], self._cfg)
        K.step_init(*a, line.s_m, line.grade, 0.0, 1.0, 1.0, 1.0)
        K.step_imu(*a, line.s_m, line.grade, line.curvature_inv_m, 0.01, 0.0, 0.0, -9.8, 0.0, 0.0, 0.0)
        K.step_odo(*a, line.s_m, line.grade, 0.05, 1.0, 0.05)
        K.step_gps(b.X[0], b.PP[0], b.AUX[0], b.CNT[0], self._cfg, line.s_m, line.east_m, line.north_m,
                   line.grade, 1.0, 1.0, 0.0, 1.5, 1)
        K.status_of(b.X[0], b.PP[0], b.AUX[0], self._cfg, 1.0)
        b.copy_slot(1, 0, keep_mem=True)
        b.set_live([0, 1], 0)
        kind = np.array([L.M_IMU, L.M_ODO, L.M_GPS], dtype=np.int64)
        vals = np.zeros((3, NV))
        vals[0, 2], vals[1, 1], vals[2, 2], vals[2, 3] = -9.8, 0.05, math.nan, 1.0
        out = RunOutput(np.zeros(3, dtype=np.int64), np.zeros(3), np.zeros((7, 4)),
                        np.zeros((4, 4), dtype=np.int64), np.zeros(3), np.zeros(3),
                        np.array([-math.inf, math.nan]), np.zeros(6, dtype=np.int64), 0)
        b.run(kind, np.array([1.01, 1.02, 1.03]), vals, 0, True, self._cfg, out)
        b.prune(self._cfg)
        b.emit(0, self._cfg, out)
        b.same_track(0, 0, self._cfg)
        b.direction_ambiguous()
        b.empty_gyro_windows()
        if not engine.is_compiled():  # the batch loop is numba-only: not in the compiled engine
            from sfa.batch import warm_up_batch

            warm_up_batch(self._cfg)

    def process(self, meas) -> Update:
        """Apply one measurement (in time order). Bad values are rejected and counted, never raised."""
        if self._bank.n and not isinstance(meas, InitMeas) and self._is_time_jump(meas):
            kind = {ImuMeas: "imu", OdoMeas: "odo", GpsMeas: "gps"}.get(type(meas), "?")
            return Update(kind, float(meas.t_s), Outcome.INVALID)
        if isinstance(meas, ImuMeas):
            return self._process_imu(meas)
        if isinstance(meas, OdoMeas):
            return self._process_odo(meas)
        if isinstance(meas, GpsMeas):
            return self._process_gps(meas)
        if isinstance(meas, InitMeas):
            return self._process_init(meas)
        raise MeasurementTypeError(f"not a filter measurement: {type(meas).__name__}")

    def run(self, kind: np.ndarray, t: np.ndarray, vals: np.ndarray, i0: int,
            out: RunOutput) -> tuple[int, int]:
        """Step packed measurements (``sfa.batch.Packed``'s arrays) from row i0 in compiled code, as
        ``process`` would one by one, with the listener's output rule after each (``out``: the result
        columns, :class:`sfa.bank.RunOutput`). Stops before a row ``process`` must take: a GROUND TRUTH
        or another kind, a row the time-jump rule looks at, any row while the filter is not initialised
        or a time jump waits for confirmation; the caller runs ``process`` on it, then :meth:`emit`.
        Relocalisations and junction branches are made here. Returns (the first row not processed, the
        rows after which the loop stopped for them)."""
        if not self.initialised or not math.isnan(self._jump_candidate):
            return i0, 0
        i = i0
        branched = 0
        while True:
            i, why = self._bank.run(kind, t, vals, i, True, self._cfg, out)
            if why != STOP_AFTER:
                return i, branched
            branched += 1
            self._after_stop()  # the last statement of process(), then the row's output
            self.emit(i, out)
            i += 1

    def emit(self, i: int, out: RunOutput) -> bool:
        """The listener's output rule (``sfa.bank.emit``) on the estimate after row i; True when sent."""
        if not self._bank.n:
            return False
        return self._bank.emit(i, self._cfg, out)

    def estimate(self, at_s: float | None = None, propagate: bool = False) -> Estimate:
        """The best hypothesis's estimate at the state time; ``at_s`` (later) only ages the time-outs.

        ``propagate``: the estimate at ``at_s`` itself, the state predicted there (the process model
        alone, its covariance grown with it) on a copy, the filter left as it is. For an announcement
        between measurements (a silent sensor timed out): the position now, with the interval that
        prediction earns, not the last measurement's position under a new date."""
        b = self._bank
        if not b.n:
            return Estimate(
                epoch_s=math.nan, arc_length_m=math.nan, speed_mps=math.nan, sigma_s_m=math.inf,
                interval_low_m=-math.inf, interval_high_m=math.inf, status=FilterStatus.INITIALISING,
                reasons=("not_initialised",), line_id=None, lat_deg=math.nan, lon_deg=math.nan,
                confidence=self._config.confidence, hypotheses=0,
            )
        r = b.reported
        line = b.line(r)
        d = b.direction(r)
        X, PP, AUX = b.X, b.PP, b.AUX
        t = float(AUX[r, L.A_T_STATE])
        t_eval = t if at_s is None or not math.isfinite(at_s) else max(t, float(at_s))
        if propagate and t_eval > t:
            # every hypothesis the interval spans (those on the reported line) predicted, on copies
            X, PP, AUX = X.copy(), PP.copy(), AUX.copy()
            for h in b.slots():
                if b.line(h) is line:
                    cnt = b.CNT[h].copy()
                    K.predict_to(X[h], PP[h], AUX[h], cnt, self._cfg, line.s_m, line.grade, t_eval)
                    K.sync_block(X[h], PP[h], AUX[h], self._cfg, cnt)
            t = t_eval
        x, P, aux = X[r], PP[r], AUX[r]
        code, bits, sigma = b.status(self._cfg, t_eval, X, PP, AUX)
        s = float(x[L.S])
        lat, lon = self._latlon(line, s)
        pv = K.pending_var_v(P, aux)
        return Estimate(
            epoch_s=t,
            arc_length_m=s,
            speed_mps=float(d * x[L.V]),
            sigma_s_m=float(sigma),
            interval_low_m=s - self._z * sigma,
            interval_high_m=s + self._z * sigma,
            status=FilterStatus(int(code)),
            reasons=reasons_from_bits(int(bits)),
            line_id=line.line_id,
            lat_deg=lat,
            lon_deg=lon,
            sigma_v_mps=math.sqrt(pv) if pv > 0 else 0.0,
            confidence=self._config.confidence,
            hypotheses=b.n,
            direction=d if b.n == 1 or not b.direction_ambiguous() else 0,
        )

    def counters(self) -> dict[str, int]:
        """Per-sensor accepted/gated/late/invalid/timed-out counts and detections (reported hypothesis)."""
        if not self._bank.n:
            return dict.fromkeys(L.COUNTER_NAMES, 0)
        cnt = self._bank.CNT[self._bank.reported]
        return {name: int(cnt[i]) for i, name in enumerate(L.COUNTER_NAMES)}

    def diagnostics(self) -> dict[str, object]:
        """Counters plus the state, its standard deviations and the line hypotheses."""
        out: dict[str, object] = {"counters": self.counters(), "hypotheses": []}
        b = self._bank
        if b.n:
            r = b.reported
            out["state"] = {n: float(v) for n, v in zip(L.STATE_NAMES, b.X[r], strict=True)}
            _, p_now = self._synced(r)
            out["sigma"] = {n: float(math.sqrt(max(p_now[i, i], 0.0))) for i, n in enumerate(L.STATE_NAMES)}
            out["last_nis_gps"] = float(b.AUX[r, L.A_LAST_NIS_GPS])
            out["last_nis_odo"] = float(b.AUX[r, L.A_LAST_NIS_ODO])
            out["hypotheses"] = [
                {"line_id": b.line(g).line_id, "direction": b.direction(g), "s_m": float(b.X[g, L.S]),
                 "loglik": float(b.AUX[g, L.A_LOGLIK])}
                for g in b.slots()
            ]
        return out

    def hypotheses(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, int]]:
        """Copies of every kept hypothesis's (state, covariance, aux, line id), the reported one first."""
        b = self._bank
        slots = b.slots()
        r = b.reported
        return [(b.X[g].copy(), b.PP[g].copy(), b.AUX[g].copy(), b.line(g).line_id)
                for g in [r] + [g for g in slots if g != r]]

    def seed(self, t_s: float, line_id: int | None, arc_length_m: float, speed_mps: float, direction: int,
             sigma_s_m: float, sigma_v_mps: float,
             errors: dict[str, tuple[float, float]] | None = None) -> Update:
        """Initialise from a saved state (a listener checkpoint) instead of a GROUND TRUTH.

        As a GROUND TRUTH at ``t_s`` on ``line_id`` with the sense of travel known (``direction`` +1:
        forward is increasing arc length, -1 decreasing; ``speed_mps`` is in the forward direction),
        then the arc-length and speed 1-sigma set to ``sigma_s_m`` and ``sigma_v_mps`` (the caller
        widens them for the time the state was not tracked) and the sensor error states restored:
        ``errors`` maps names of :data:`sfa.layout.STATE_NAMES` other than ``s_m``/``v_mps`` to (value,
        1-sigma); their cross-covariances start at zero. Returns the initialisation's Update
        (``Outcome.INVALID`` and nothing changed on a bad value)."""
        values = (t_s, arc_length_m, speed_mps, sigma_s_m, sigma_v_mps)
        finite = all(isinstance(v, float | int) and math.isfinite(v) for v in values)
        if direction not in (1, -1, 0) or not finite or sigma_s_m <= 0.0 or sigma_v_mps <= 0.0:
            return Update("init", float(t_s) if isinstance(t_s, float | int) else math.nan, Outcome.INVALID)
        slots: dict[int, tuple[float, float]] = {}
        for name, pair in (errors or {}).items():
            if name not in L.STATE_NAMES or name in ("s_m", "v_mps"):
                return Update("init", float(t_s), Outcome.INVALID)
            value, sigma = (float(p) for p in pair)
            if not (math.isfinite(value) and math.isfinite(sigma) and sigma >= 0.0):
                return Update("init", float(t_s), Outcome.INVALID)
            slots[L.STATE_NAMES.index(name)] = (value, sigma)
        upd = self._process_init(InitMeas(float(t_s), float(arc_length_m), float(speed_mps), line_id,
                                          direction=int(direction) or None))
        if upd.outcome != Outcome.INITIALISED:
            return upd
        b = self._bank
        for h in b.slots():
            x, P = b.X[h], b.PP[h]
            for i, (value, sigma) in slots.items():
                x[i] = value
                P[i, :] = 0.0
                P[:, i] = 0.0
                P[i, i] = sigma * sigma
            P[L.S, L.S] = float(sigma_s_m) ** 2
            P[L.V, L.V] = float(sigma_v_mps) ** 2
        return upd

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of the reported hypothesis's state vector and covariance (indices in sfa.layout)."""
        if not self._bank.n:
            raise FilterStateError("the filter is not initialised")
        return self._synced(self._bank.reported)

    def _synced(self, slot: int) -> tuple[np.ndarray, np.ndarray]:
        """Copies of x and P of ``slot`` brought up to the state time, leaving the slot as it is (reading
        the state must not change the filter's arithmetic: a replay that reads it less often gives the
        same)."""
        b = self._bank
        x, P, aux = b.X[slot].copy(), b.PP[slot].copy(), b.AUX[slot].copy()
        K.sync_block(x, P, aux, self._cfg, b.CNT[slot].copy())
        return x, P

    # ------------------------------------------------------------------ measurements
    def _process_init(self, m: InitMeas) -> Update:
        try:
            line = self.line_arrays(m.line_id)
        except self._track_errors:
            return Update("init", m.t_s, Outcome.INVALID)
        try:
            t, s, v = float(m.t_s), float(m.arc_length_m), float(m.speed_mps)
            directions = (1.0, -1.0) if m.direction is None else (float(m.direction),)
        except (TypeError, ValueError):
            return Update("init", math.nan, Outcome.INVALID)
        b = self._bank
        new: list[int] = []
        code = K.O_INVALID
        for d in directions:
            h = b.new_slot(new)
            if b.n:
                b.copy_slot(h, b.reported, keep_mem=True)
            else:
                b.clear_slot(h)
            b.place(h, line, frozenset())
            code = K.step_init(b.X[h], b.PP[h], b.AUX[h], b.CNT[h], b.MEM[h], self._cfg, line.s_m, line.grade,
                               t, s, v, d)
            if code != K.O_INITIALISED:
                break
            new.append(h)
        if code == K.O_INITIALISED:
            b.set_live(new, 0)
            self._spawn_branches()
        return Update("init", t, Outcome(code))

    def _step(self, kind: int, t: float) -> tuple[int, float]:
        """Run the bank's loop over the one measurement in ``_vals1``; (outcome, NIS)."""
        self._kind1[0] = kind
        self._t1[0] = t
        out = self._out1
        _, why = self._bank.run(self._kind1, self._t1, self._vals1, 0, False, self._cfg, out)
        if why == STOP_AFTER:
            self._after_stop()
        return int(out.u_out[0]), float(out.u_nis[0])

    def _process_imu(self, m: ImuMeas) -> Update:
        try:
            fx, fy, fz = (float(v) for v in m.f_mps2)
            wx, wy, wz = (float(v) for v in m.w_radps)
            t = float(m.t_s)
        except (TypeError, ValueError):
            return self._invalid("imu", m, L.C_IMU_BAD)
        if not self._bank.n:
            return Update("imu", t, Outcome.NOT_INITIALISED)
        v = self._vals1[0]
        v[0], v[1], v[2], v[3], v[4], v[5] = fx, fy, fz, wx, wy, wz
        code, _ = self._step(L.M_IMU, t)
        return Update("imu", t, Outcome(code))

    def _process_odo(self, m: OdoMeas) -> Update:
        try:
            t, speed, sg = float(m.t_s), float(m.speed_mps), float(m.sigma_mps)
        except (TypeError, ValueError):
            return self._invalid("odo", m, L.C_ODO_BAD)
        if not self._bank.n:
            return Update("odo", t, Outcome.NOT_INITIALISED)
        v = self._vals1[0]
        v[0], v[1] = speed, sg
        code, nis = self._step(L.M_ODO, t)
        return Update("odo", t, Outcome(code), nis)

    def _process_gps(self, m: GpsMeas) -> Update:
        try:
            t, lat, lon = float(m.t_s), float(m.lat_deg), float(m.lon_deg)
            sigma_h = math.nan if m.sigma_h_m is None else float(m.sigma_h_m)
            fq = -1 if m.fix_quality is None else int(m.fix_quality)
        except (TypeError, ValueError):
            return self._invalid("gps", m, L.C_GPS_BAD)
        if not self._bank.n:
            return Update("gps", t, Outcome.NOT_INITIALISED)
        if fq == 0:
            east = north = 0.0
        elif not (math.isfinite(lat) and math.isfinite(lon)) or abs(lat) > 90.0 or abs(lon) > 180.0:
            east = north = math.nan
        else:
            east, north = self._track.to_local(lat, lon)
            east, north = float(east), float(north)
        v = self._vals1[0]
        v[0], v[1], v[2], v[3] = east, north, sigma_h, float(fq)
        code, nis = self._step(L.M_GPS, t)
        return Update("gps", t, Outcome(code), nis)

    def _is_time_jump(self, meas) -> bool:
        """A measurement more than max_time_jump_s ahead of the state (a corrupted epoch, say) is
        rejected unless the measurement just before it was also such a jump to within 1 s: a real gap
        of the whole sensor set is confirmed by the next measurement, a single bad epoch is not."""
        try:
            t = float(meas.t_s)
        except (TypeError, ValueError, AttributeError):
            return False
        t_state = float(self._bank.AUX[self._bank.reported, L.A_T_STATE])
        if not (math.isfinite(t) and t - t_state > self._config.max_time_jump_s):
            self._jump_candidate = math.nan
            return False
        confirmed = math.isfinite(self._jump_candidate) and abs(t - self._jump_candidate) <= 1.0
        self._jump_candidate = t
        if confirmed:
            self._jump_candidate = math.nan
            return False
        self._count_all(L.C_TIME_JUMP, 1)
        return True

    def _invalid(self, kind: str, m, counter: int) -> Update:
        self._count_all(counter, 1)
        t = m.t_s if isinstance(getattr(m, "t_s", None), float | int) else math.nan
        return Update(kind, float(t), Outcome.INVALID)

    def _count_all(self, counter: int, n: int) -> None:
        b = self._bank
        for h in b.slots():
            b.CNT[h, counter] += n

    # ------------------------------------------------------------------ lines and junctions
    def preload_lines(self) -> int:
        """Load every line of the database now (the daemon calls this before READY, so memory stays
        flat and no junction pays a load while the train runs); returns the number of lines."""
        for info in self._track.lines():
            self.line_arrays(info.line_id)
        return len(self._lines)

    def line_arrays(self, line_id: int | None) -> TrackArrays:
        """The kernels' arrays of line ``line_id`` (the database's default line for None), loaded once."""
        key = self._track.default_line_id if line_id is None else int(line_id)
        arr = self._lines.get(key)
        if arr is None:
            arr = TrackArrays.from_line(self._track.line(key))
            self._lines[key] = arr
        return arr

    @staticmethod
    def _latlon(line: TrackArrays, s: float) -> tuple[float, float]:
        """Latitude/longitude by linear interpolation between points a few metres apart (the geodetic
        curvature between them is far below a millimetre); NaN off the ends of the line."""
        if line.lat_deg is None or not line.s_m[0] <= s <= line.s_m[-1]:
            return math.nan, math.nan
        return (float(K.interp_at(line.s_m, line.lat_deg, s)), float(K.interp_at(line.s_m, line.lon_deg, s)))

    def _junction_map(self) -> dict[int, tuple[list[float], list[tuple[int, float, int, float]]]]:
        """line_id -> (sorted s on this line, [(junction key, s on this line, other line, s on the other
        line)] in the same order), both directions of every junction."""
        if self._junctions is None:
            rows: dict[int, list[tuple[int, float, int, float]]] = {}
            try:
                junctions = list(self._track.junctions()) if hasattr(self._track, "junctions") else []
            except self._track_errors:
                junctions = []
            for k, j in enumerate(junctions):
                rows.setdefault(int(j.line_a), []).append((k, float(j.s_a_m), int(j.line_b), float(j.s_b_m)))
                rows.setdefault(int(j.line_b), []).append((k, float(j.s_b_m), int(j.line_a), float(j.s_a_m)))
            jmap = {}
            for line_id, items in rows.items():
                items.sort(key=lambda r: r[1])
                jmap[line_id] = ([r[1] for r in items], items)
            self._junctions = jmap
        return self._junctions

    def _junction_s(self, line_id: int) -> list[tuple[int, float]]:
        """(junction key, s on the line) of every junction on ``line_id`` (the bank's junction windows)."""
        entry = self._junction_map().get(line_id)
        return [] if entry is None else [(key, s) for key, s, _, _ in entry[1]]

    def _after_stop(self) -> None:
        """What the bank's loop stops for (STOP_AFTER): a relocalisation, then the junction branches."""
        self._relocalise()
        self._spawn_branches()

    def _relocalise(self) -> None:
        """The reported hypothesis rejected every fix for ``reacquire_s`` and the fixes did not agree
        along its line (kernels.step_gps set A_RELOC): it may be on the wrong line (a branch chosen at a
        diverging junction before the lines had parted). Add a hypothesis on each line of the network
        the fixes do agree along, the test the reacquisition makes on the hypothesis's own line: the
        run's last fix within the GNSS gate of the line (its first within that or
        ``reacquire_consistency_m``), and the arc length between their projections within
        ``reacquire_consistency_m`` of the distance the hypothesis travelled meanwhile. Fixes drifting
        against the odometer (a multipath ramp) agree along no line and move nothing. The new hypothesis
        is the parent's state with the last fix's arc length (its variance the fix's along-track error),
        the sense of travel the fixes show on its line, the GNSS error state restarted and the parent's
        score; the GNSS score then keeps whichever the fixes agree with, as at a junction, and the
        parent stays alive until then."""
        b = self._bank
        rep = b.reported
        if b.AUX[rep, L.A_RELOC] == 0.0:
            return
        b.AUX[rep, L.A_RELOC] = 0.0
        aux_rep = b.AUX[rep]
        east, north = float(aux_rep[L.A_RELOC_E]), float(aux_rep[L.A_RELOC_N])
        east0, north0 = float(aux_rep[L.A_RELOC_E0]), float(aux_rep[L.A_RELOC_N0])
        travelled = float(aux_rep[L.A_RELOC_DS])
        if not all(math.isfinite(v) for v in (east, north, east0, north0, travelled)):
            return
        cfg = self._cfg
        gm, gw = float(aux_rep[L.A_GM_SIG]), float(aux_rep[L.A_GW_SIG])
        var_fix = gm * gm + gw * gw + float(cfg[L.K_TRACK_LAT]) ** 2  # per axis [m^2]
        radius = math.sqrt(float(cfg[L.K_GATE_GPS]) * var_fix)
        parent = b.line(rep)
        d = b.direction(rep)
        _, _, pde, pdn = K.geom_at(parent.s_m, parent.east_m, parent.north_m, float(b.X[rep, L.S]))
        new: list[int] = []
        consistency = float(cfg[L.K_REACQ_CONSIST_M])
        for info in self._track.lines():
            try:
                s_proj, offset = self._track.line(info.line_id).project([east, east0], [north, north0])
                line = self.line_arrays(info.line_id)
            except self._track_errors:
                continue
            if not (abs(float(offset[0])) <= radius and abs(float(offset[1])) <= max(radius, consistency)):
                continue
            s_last, s_first = float(s_proj[0]), float(s_proj[1])
            if line.line_id == parent.line_id and abs(s_last - float(b.X[rep, L.S])) < 1.0:
                continue  # where the parent already is
            if not abs(abs(s_last - s_first) - abs(travelled)) <= consistency:
                continue  # the fixes do not move along this line as the train did
            if abs(s_last - s_first) > consistency:  # the sense of travel the fixes show on this line
                same_way = (s_last > s_first) == (travelled > 0.0)
            else:  # (nearly) at a standstill: the parent's heading, as near as its line gives it
                _, _, de, dn = K.geom_at(line.s_m, line.east_m, line.north_m, s_last)
                same_way = d * (de * pde + dn * pdn) >= 0.0
            g = b.new_slot(new)
            keys = b.spawned(rep) if line.line_id == parent.line_id else frozenset()
            self._copy_to(rep, g, line, s_last, keys, flip=(d > 0) != same_way)
            x, P, aux = b.X[g], b.PP[g], b.AUX[g]
            P[L.S, :] = 0.0  # re-anchored on the fix: no correlation with the rest
            P[:, L.S] = 0.0
            P[L.S, L.S] = var_fix
            K.restart_gnss_error(x, P, aux)  # a new line: the fixes' error and residuals start afresh
            aux[L.A_GPS_REJ] = 0.0
            aux[L.A_STEP_FLAG] = 0.0
            aux[L.A_CUSUM_P] = aux[L.A_CUSUM_N] = 0.0
            new.append(g)
        if new:
            for h in [rep, *new]:  # one relocalisation, in the counters of whichever is kept
                b.CNT[h, L.C_RELOC] += 1
        self._add_live(new)

    def _spawn_branches(self) -> None:
        """Add a hypothesis on every line that branches off within the look-ahead window."""
        jmap = self._junction_map()
        if not jmap:
            return
        window = self._config.junction_window_m
        b = self._bank
        new: list[int] = []
        for h in b.slots():
            line = b.line(h)
            entry = jmap.get(line.line_id)
            if entry is None:
                continue
            s_list, items = entry
            s = float(b.X[h, L.S])
            lo, hi = bisect.bisect_left(s_list, s - window), bisect.bisect_right(s_list, s + window)
            for key, s_here, other, s_other in items[lo:hi]:
                spawned = b.spawned(h)
                if key in spawned:
                    continue
                spawned = spawned | {key}
                b.set_spawned(h, spawned)
                try:
                    other_line = self.line_arrays(other)
                except self._track_errors:
                    continue
                # direction of the other line relative to this one at the junction
                _, _, de_a, dn_a = K.geom_at(line.s_m, line.east_m, line.north_m, s_here)
                _, _, de_b, dn_b = K.geom_at(other_line.s_m, other_line.east_m, other_line.north_m, s_other)
                g = b.new_slot(new)
                if de_a * de_b + dn_a * dn_b >= 0.0:
                    self._copy_to(h, g, other_line, s_other + (s - s_here), spawned, flip=False)
                else:  # arc length of the other line runs the other way at the junction
                    self._copy_to(h, g, other_line, s_other - (s - s_here), spawned, flip=True)
                new.append(g)
        self._add_live(new)

    def _add_live(self, new: list[int]) -> None:
        """Make the slots ``new`` (spawned from live hypotheses) live beside them: every gyro window
        emptied so that all close at the same sample, pruned, the junction sets compacted."""
        b = self._bank
        if new:
            b.set_live(b.slots() + new, int(b.ns[1]))
            b.empty_gyro_windows()
            b.prune(self._cfg)
        b.compact()

    def _copy_to(self, h: int, g: int, line: TrackArrays, s_m: float, keys: frozenset, flip: bool) -> None:
        """Slot g = a copy of slot h on ``line`` at ``s_m`` (h's P synced first); ``flip`` when arc length
        runs the other way there (s and v change sign, and so do their covariance rows/columns)."""
        b = self._bank
        K.sync_block(b.X[h], b.PP[h], b.AUX[h], self._cfg, b.CNT[h])
        b.copy_slot(g, h)  # snapshots are on the other line: not reusable
        b.place(g, line, keys)
        b.X[g, L.S] = s_m
        if flip:
            b.X[g, L.V] = -b.X[g, L.V]
            b.AUX[g, L.A_DIR] = -b.AUX[g, L.A_DIR]
            P = b.PP[g]
            for i in (L.S, L.V):
                P[i, :] = -P[i, :]
                P[:, i] = -P[:, i]
