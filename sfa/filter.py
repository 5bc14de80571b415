"""TrackFilter: the per-message face of the track-constrained EKF, with line hypotheses at junctions.

The mathematics lives in ``sfa.kernels`` (compiled); this class owns the state arrays of one or more
line hypotheses, converts measurements into kernel calls, and turns the arrays into typed results.
It never reads a clock: every time comes with a measurement or as an argument.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np

from sfa import engine, gnss_noise
from sfa import kernels as K
from sfa import layout as L
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


@dataclass(eq=False)
class _Hypothesis:
    """State arrays of one line hypothesis."""

    line: TrackArrays
    x: np.ndarray = field(default_factory=lambda: np.zeros(L.NX))
    P: np.ndarray = field(default_factory=lambda: np.zeros((L.NX, L.NX)))
    aux: np.ndarray = field(default_factory=lambda: np.zeros(L.NAUX))
    cnt: np.ndarray = field(default_factory=lambda: np.zeros(L.NCNT, dtype=np.int64))
    spawned: frozenset = frozenset()  #: junction keys this lineage already branched at
    mem: np.ndarray = field(default_factory=lambda: np.zeros(L.NMEM))  #: rewind snapshots and IMU ring

    def clone(self, line: TrackArrays | None = None, spawned: frozenset | None = None) -> _Hypothesis:
        return _Hypothesis(self.line if line is None else line, self.x.copy(), self.P.copy(), self.aux.copy(),
                           self.cnt.copy(), self.spawned if spawned is None else spawned, self.mem.copy())

    @property
    def direction(self) -> int:
        return int(self.aux[L.A_DIR])

    def sync(self, cfg: np.ndarray) -> None:
        """Bring P up to the state time (``sfa.kernels.sync_block``): before P is copied and transformed."""
        K.sync_block(self.x, self.P, self.aux, cfg, self.cnt)

    def synced(self, cfg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Copies of x and P brought up to the state time, leaving this hypothesis as it is (reading the
        state must not change the filter's arithmetic: a replay that reads it less often gives the same)."""
        x, P, aux = self.x.copy(), self.P.copy(), self.aux.copy()
        K.sync_block(x, P, aux, cfg, self.cnt.copy())
        return x, P

    def copy_to(self, line: TrackArrays, s_m: float, keys: frozenset, cfg: np.ndarray,
                flip: bool = False) -> _Hypothesis:
        """A copy on ``line`` at ``s_m``; ``flip`` when arc length runs the other way there (s and v
        change sign, and so do their covariance rows/columns). Syncs this hypothesis's P first."""
        self.sync(cfg)
        h = self.clone(line, keys)
        h.x[L.S] = s_m
        h.mem[:] = 0.0  # snapshots are on the other line: not reusable
        if flip:
            h.x[L.V] = -h.x[L.V]
            h.aux[L.A_DIR] = -h.aux[L.A_DIR]
            for i in (L.S, L.V):
                h.P[i, :] = -h.P[i, :]
                h.P[:, i] = -h.P[:, i]
        return h

    def mirrored(self, cfg: np.ndarray) -> _Hypothesis:
        """Same place, opposite sense of travel (the train may reverse while standing). Syncs this
        hypothesis's P first."""
        self.sync(cfg)
        h = self.clone()
        h.mem[:] = 0.0
        K.mirror(h.x, h.P, h.aux)
        return h


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
    ``estimate`` reports the best hypothesis.
    """

    def __init__(self, track, config: FilterConfig | None = None) -> None:
        self._track = track
        self._config = config if config is not None else FilterConfig()
        if not isinstance(self._config, FilterConfig):
            raise FilterStateError(f"config must be a FilterConfig, got {type(self._config).__name__}")
        self._cfg = self._config.to_array()
        self._z = float(self._cfg[L.K_Z_INTERVAL])
        self._lines: dict[int, TrackArrays] = {}
        self._hyps: list[_Hypothesis] = []
        self._reported = 0  # index into _hyps of the reported hypothesis
        self._junctions = None  # built lazily: line_id -> list of (key, s_on_line, other_line, s_other)
        self._track_errors = _track_errors()
        self._jump_candidate = math.nan  # time of the last measurement rejected as a forward time jump

    # ------------------------------------------------------------------ public API
    @property
    def config(self) -> FilterConfig:
        return self._config

    @property
    def initialised(self) -> bool:
        return bool(self._hyps) and self._hyps[0].aux[L.A_INIT] != 0.0

    def warm_up(self) -> None:
        """Compile (or load from cache) every kernel on a throwaway two-vertex line."""
        line = TrackArrays(0, 100.0, np.array([0.0, 100.0]), np.array([0.0, 100.0]), np.zeros(2),
                           np.zeros(2), np.zeros(2))
        h = _Hypothesis(line)
        a = (h.x, h.P, h.aux, h.cnt, h.mem, self._cfg)
        K.step_init(*a, line.s_m, line.grade, 0.0, 1.0, 1.0, 1.0)
        K.step_imu(*a, line.s_m, line.grade, line.curvature_inv_m, 0.01, 0.0, 0.0, -9.8, 0.0, 0.0, 0.0)
        K.step_odo(*a, line.s_m, line.grade, 0.05, 1.0, 0.05)
        K.step_gps(h.x, h.P, h.aux, h.cnt, self._cfg, line.s_m, line.east_m, line.north_m, line.grade,
                   1.0, 1.0, 0.0, 1.5, 1)
        K.status_of(h.x, h.P, h.aux, self._cfg, 1.0)
        if not engine.is_compiled():  # the batch loop is numba-only: not in the compiled engine
            from sfa.batch import warm_up_batch

            warm_up_batch(self._cfg)

    def process(self, meas) -> Update:
        """Apply one measurement (in time order). Bad values are rejected and counted, never raised."""
        if self._hyps and not isinstance(meas, InitMeas) and self._is_time_jump(meas):
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

    def estimate(self, at_s: float | None = None, propagate: bool = False) -> Estimate:
        """The best hypothesis's estimate at the state time; ``at_s`` (later) only ages the time-outs.

        ``propagate``: the estimate at ``at_s`` itself, the state predicted there (the process model
        alone, its covariance grown with it) on a copy, the filter left as it is. For an announcement
        between measurements (a silent sensor timed out): the position now, with the interval that
        prediction earns, not the last measurement's position under a new date."""
        if not self._hyps:
            return Estimate(
                epoch_s=math.nan, arc_length_m=math.nan, speed_mps=math.nan, sigma_s_m=math.inf,
                interval_low_m=-math.inf, interval_high_m=math.inf, status=FilterStatus.INITIALISING,
                reasons=("not_initialised",), line_id=None, lat_deg=math.nan, lon_deg=math.nan,
                confidence=self._config.confidence, hypotheses=0,
            )
        h = self._hyps[self._reported]
        d = h.direction
        t = float(h.aux[L.A_T_STATE])
        t_eval = t if at_s is None or not math.isfinite(at_s) else max(t, float(at_s))
        if propagate and t_eval > t:
            h = h.clone()
            K.predict_to(h.x, h.P, h.aux, h.cnt, self._cfg, h.line.s_m, h.line.grade, t_eval)
            h.sync(self._cfg)
            t = t_eval
        code, bits, sigma = K.status_of(h.x, h.P, h.aux, self._cfg, t_eval)
        s = float(h.x[L.S])
        lat, lon = self._latlon(h.line, s)
        pv = K.pending_var_v(h.P, h.aux)
        return Estimate(
            epoch_s=t,
            arc_length_m=s,
            speed_mps=float(d * h.x[L.V]),
            sigma_s_m=float(sigma),
            interval_low_m=s - self._z * sigma,
            interval_high_m=s + self._z * sigma,
            status=FilterStatus(int(code)),
            reasons=reasons_from_bits(int(bits)),
            line_id=h.line.line_id,
            lat_deg=lat,
            lon_deg=lon,
            sigma_v_mps=math.sqrt(pv) if pv > 0 else 0.0,
            confidence=self._config.confidence,
            hypotheses=len(self._hyps),
            direction=d if len(self._hyps) == 1 or not self._direction_ambiguous() else 0,
        )

    def _direction_ambiguous(self) -> bool:
        h = self._hyps[self._reported]
        return any(g.line.line_id == h.line.line_id and g.direction != h.direction
                   and abs(g.x[L.S] - h.x[L.S]) < 1.0 for g in self._hyps)

    def counters(self) -> dict[str, int]:
        """Per-sensor accepted/gated/late/invalid/timed-out counts and detections (reported hypothesis)."""
        if not self._hyps:
            return dict.fromkeys(L.COUNTER_NAMES, 0)
        cnt = self._hyps[self._reported].cnt
        return {name: int(cnt[i]) for i, name in enumerate(L.COUNTER_NAMES)}

    def diagnostics(self) -> dict[str, object]:
        """Counters plus the state, its standard deviations and the line hypotheses."""
        out: dict[str, object] = {"counters": self.counters(), "hypotheses": []}
        if self._hyps:
            h = self._hyps[self._reported]
            out["state"] = {n: float(v) for n, v in zip(L.STATE_NAMES, h.x, strict=True)}
            _, p_now = h.synced(self._cfg)
            out["sigma"] = {n: float(math.sqrt(max(p_now[i, i], 0.0))) for i, n in enumerate(L.STATE_NAMES)}
            out["last_nis_gps"] = float(h.aux[L.A_LAST_NIS_GPS])
            out["last_nis_odo"] = float(h.aux[L.A_LAST_NIS_ODO])
            out["hypotheses"] = [
                {"line_id": g.line.line_id, "direction": g.direction, "s_m": float(g.x[L.S]),
                 "loglik": float(g.aux[L.A_LOGLIK])}
                for g in self._hyps
            ]
        return out

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
        for h in self._hyps:
            for i, (value, sigma) in slots.items():
                h.x[i] = value
                h.P[i, :] = 0.0
                h.P[:, i] = 0.0
                h.P[i, i] = sigma * sigma
            h.P[L.S, L.S] = float(sigma_s_m) ** 2
            h.P[L.V, L.V] = float(sigma_v_mps) ** 2
        return upd

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of the reported hypothesis's state vector and covariance (indices in sfa.layout)."""
        if not self._hyps:
            raise FilterStateError("the filter is not initialised")
        return self._hyps[self._reported].synced(self._cfg)

    # ------------------------------------------------------------------ measurements
    def _process_init(self, m: InitMeas) -> Update:
        try:
            line = self._line_arrays(m.line_id)
        except self._track_errors:
            return Update("init", m.t_s, Outcome.INVALID)
        try:
            t, s, v = float(m.t_s), float(m.arc_length_m), float(m.speed_mps)
            directions = (1.0, -1.0) if m.direction is None else (float(m.direction),)
        except (TypeError, ValueError):
            return Update("init", math.nan, Outcome.INVALID)
        new: list[_Hypothesis] = []
        code = K.O_INVALID
        for d in directions:
            if self._hyps:
                base = self._hyps[self._reported]
                h = base.clone(line, frozenset())
            else:
                h = _Hypothesis(line)
            code = K.step_init(h.x, h.P, h.aux, h.cnt, h.mem, self._cfg, line.s_m, line.grade, t, s, v, d)
            if code != K.O_INITIALISED:
                break
            new.append(h)
        if code == K.O_INITIALISED:
            self._hyps = new
            self._reported = 0
            self._spawn_branches()
        return Update("init", t, Outcome(code))

    def _process_imu(self, m: ImuMeas) -> Update:
        try:
            fx, fy, fz = (float(v) for v in m.f_mps2)
            wx, wy, wz = (float(v) for v in m.w_radps)
            t = float(m.t_s)
        except (TypeError, ValueError):
            return self._invalid("imu", m, L.C_IMU_BAD)
        if not self._hyps:
            return Update("imu", t, Outcome.NOT_INITIALISED)
        code = K.O_INVALID
        for i, h in enumerate(self._hyps):
            c = K.step_imu(h.x, h.P, h.aux, h.cnt, h.mem, self._cfg, h.line.s_m, h.line.grade,
                           h.line.curvature_inv_m, t, fx, fy, fz, wx, wy, wz)
            if i == self._reported:
                code = c
        if len(self._hyps) > 1 and all(h.aux[L.A_LAST_NIS_GYRO] >= 0.0 for h in self._hyps) \
                and any(h.aux[L.A_GYRO_OK] != 0.0 for h in self._hyps):
            self._score(L.A_LAST_NIS_GYRO)  # the yaw rate tells branches apart by their curvature
        return Update("imu", t, Outcome(code))

    def _process_odo(self, m: OdoMeas) -> Update:
        try:
            t, v, sg = float(m.t_s), float(m.speed_mps), float(m.sigma_mps)
        except (TypeError, ValueError):
            return self._invalid("odo", m, L.C_ODO_BAD)
        if not self._hyps:
            return Update("odo", t, Outcome.NOT_INITIALISED)
        code = K.O_INVALID
        accepted_by_any = False
        for i, h in enumerate(self._hyps):
            c = K.step_odo(h.x, h.P, h.aux, h.cnt, h.mem, self._cfg, h.line.s_m, h.line.grade, t, v, sg)
            accepted_by_any |= c == K.O_ACCEPTED
            if i == self._reported:
                code = c
        nis = float(self._hyps[self._reported].aux[L.A_LAST_NIS_ODO])
        if len(self._hyps) > 1 and accepted_by_any:
            self._score(L.A_LAST_NIS_ODO)
        if self._hyps[self._reported].aux[L.A_STILL] != 0.0 and self._config.reversal_hypotheses:
            self._spawn_reversals()
        if self._junction_map() and code == K.O_ACCEPTED:
            self._spawn_branches()
        return Update("odo", t, Outcome(code), nis)

    def _process_gps(self, m: GpsMeas) -> Update:
        try:
            t, lat, lon = float(m.t_s), float(m.lat_deg), float(m.lon_deg)
            sigma_h = math.nan if m.sigma_h_m is None else float(m.sigma_h_m)
            fq = -1 if m.fix_quality is None else int(m.fix_quality)
        except (TypeError, ValueError):
            return self._invalid("gps", m, L.C_GPS_BAD)
        if not self._hyps:
            return Update("gps", t, Outcome.NOT_INITIALISED)
        if fq == 0:
            east = north = 0.0
        elif not (math.isfinite(lat) and math.isfinite(lon)) or abs(lat) > 90.0 or abs(lon) > 180.0:
            east = north = math.nan
        else:
            east, north = self._track.to_local(lat, lon)
            east, north = float(east), float(north)
        code = K.O_INVALID
        accepted_by_any = False
        rep_aux = self._hyps[self._reported].aux
        for i, h in enumerate(self._hyps):  # one GNSS model, the reported hypothesis's (gnss_noise.share)
            gnss_noise.share(h.aux, rep_aux, i == self._reported)
        for i, h in enumerate(self._hyps):
            c = K.step_gps(h.x, h.P, h.aux, h.cnt, self._cfg, h.line.s_m, h.line.east_m, h.line.north_m,
                           h.line.grade, t, east, north, sigma_h, fq)
            accepted_by_any |= c == K.O_ACCEPTED
            if i == self._reported:
                code = c
        nis = float(self._hyps[self._reported].aux[L.A_LAST_NIS_GPS])
        if len(self._hyps) > 1 and accepted_by_any:
            self._score(L.A_LAST_NIS_GPS)
        if self._junction_map():
            self._spawn_branches()
        return Update("gps", t, Outcome(code), nis)

    def _is_time_jump(self, meas) -> bool:
        """A measurement more than max_time_jump_s ahead of the state (a corrupted epoch, say) is
        rejected unless the measurement just before it was also such a jump to within 1 s: a real gap
        of the whole sensor set is confirmed by the next measurement, a single bad epoch is not."""
        try:
            t = float(meas.t_s)
        except (TypeError, ValueError, AttributeError):
            return False
        t_state = float(self._hyps[self._reported].aux[L.A_T_STATE])
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

    def _score(self, nis_slot: int) -> None:
        """Hypothesis score: robust log-likelihood -NIS/2 (capped) of GNSS fixes, odometer and gyro
        samples that at least one hypothesis accepted (a measurement every hypothesis rejects is a sensor
        fault, not evidence for one of them); then prune."""
        cap = self._config.loglik_nis_cap
        for h in self._hyps:
            h.aux[L.A_LOGLIK] -= 0.5 * min(float(h.aux[nis_slot]), cap)
        self._prune()

    def _invalid(self, kind: str, m, counter: int) -> Update:
        self._count_all(counter, 1)
        t = m.t_s if isinstance(getattr(m, "t_s", None), float | int) else math.nan
        return Update(kind, float(t), Outcome.INVALID)

    def _count_all(self, counter: int, n: int) -> None:
        for h in self._hyps:
            h.cnt[counter] += n

    # ------------------------------------------------------------------ lines and junctions
    def preload_lines(self) -> int:
        """Load every line of the database now (the daemon calls this before READY, so memory stays
        flat and no junction pays a load while the train runs); returns the number of lines."""
        for info in self._track.lines():
            self._line_arrays(info.line_id)
        return len(self._lines)

    def _line_arrays(self, line_id: int | None) -> TrackArrays:
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

    def _spawn_reversals(self) -> None:
        """At standstill the train may change its sense of travel: keep the mirrored hypothesis too."""
        new = []
        for h in self._hyps:
            if h.aux[L.A_STILL] == 0.0:
                continue
            if any(g.line.line_id == h.line.line_id and g.direction != h.direction
                   and abs(g.x[L.S] - h.x[L.S]) < 1.0 for g in self._hyps + new):
                continue
            new.append(h.mirrored(self._cfg))
        if new:
            self._hyps.extend(new)
            self._empty_gyro_windows()
            self._prune()

    def _spawn_branches(self) -> None:
        """Add a hypothesis on every line that branches off within the look-ahead window."""
        jmap = self._junction_map()
        if not jmap:
            return
        window = self._config.junction_window_m
        new: list[_Hypothesis] = []
        for h in self._hyps:
            entry = jmap.get(h.line.line_id)
            if entry is None:
                continue
            s_list, items = entry
            s = float(h.x[L.S])
            lo, hi = bisect.bisect_left(s_list, s - window), bisect.bisect_right(s_list, s + window)
            for key, s_here, other, s_other in items[lo:hi]:
                if key in h.spawned:
                    continue
                h.spawned = h.spawned | {key}
                try:
                    other_line = self._line_arrays(other)
                except self._track_errors:
                    continue
                # direction of the other line relative to this one at the junction
                _, _, de_a, dn_a = K.geom_at(h.line.s_m, h.line.east_m, h.line.north_m, s_here)
                _, _, de_b, dn_b = K.geom_at(other_line.s_m, other_line.east_m, other_line.north_m, s_other)
                if de_a * de_b + dn_a * dn_b >= 0.0:
                    new.append(h.copy_to(other_line, s_other + (s - s_here), h.spawned, self._cfg))
                else:  # arc length of the other line runs the other way at the junction
                    new.append(h.copy_to(other_line, s_other - (s - s_here), h.spawned, self._cfg, flip=True))
        if new:
            self._hyps.extend(new)
            self._empty_gyro_windows()
            self._prune()

    def _empty_gyro_windows(self) -> None:
        """After new hypotheses: every gyro window starts empty, so that all close at the same sample (the
        likelihood compares their NIS there) and none of a copy's residuals, taken on its parent's line
        or sense of travel, is applied to it."""
        for g in self._hyps:
            g.aux[L.A_GY_N] = 0.0

    def _same_track(self, g: _Hypothesis, h: _Hypothesis) -> bool:
        """True when h duplicates g: the same line, sense of travel and place (within 1 m); or another
        line that runs on g's track: the same place and way of travel in the plane now and 2 x the
        junction window ahead (several routes of a network share one track: hypotheses on them cannot
        be told apart until the lines part, where that junction spawns them again). A branch just
        spawned is not a duplicate: 2 x the window ahead reaches at least one window past its junction,
        where the lines have parted."""
        if g.line.line_id == h.line.line_id:
            return g.direction == h.direction and abs(g.x[L.S] - h.x[L.S]) < 1.0
        ahead = 2.0 * self._config.junction_window_m
        pts = []
        for q in (g, h):
            s0 = float(q.x[L.S])
            s1 = s0 + q.direction * ahead
            ln = q.line
            if not (ln.s_m[0] <= s0 <= ln.s_m[-1] and ln.s_m[0] <= s1 <= ln.s_m[-1]):
                return False
            e0, n0, de, dn = K.geom_at(ln.s_m, ln.east_m, ln.north_m, s0)
            e1, n1, _, _ = K.geom_at(ln.s_m, ln.east_m, ln.north_m, s1)
            pts.append((e0, n0, e1, n1, q.direction * de, q.direction * dn))
        (ga, gb, gc, gd, gu, gv), (ha, hb, hc, hd, hu, hv) = pts
        return (math.hypot(ga - ha, gb - hb) < 1.0 and math.hypot(gc - hc, gd - hd) < 1.0
                and gu * hu + gv * hv > 0.0)

    def _prune(self) -> None:
        """Drop hypotheses whose GNSS log-likelihood trails the best by more than prune_log_ratio,
        duplicates (``_same_track``) and the excess over max_hypotheses."""
        reported = self._hyps[self._reported]
        best = max(float(h.aux[L.A_LOGLIK]) for h in self._hyps)
        keep: list[_Hypothesis] = []
        order = sorted(self._hyps, key=lambda h: (h is not reported, -float(h.aux[L.A_LOGLIK])))
        for h in order:
            if float(h.aux[L.A_LOGLIK]) < best - self._config.prune_log_ratio:
                continue
            margin = self._config.junction_window_m
            if h.x[L.S] > h.line.length_m + margin or h.x[L.S] < -margin:
                if len(order) > 1:
                    continue  # ran off the end of its line while others remain
            if any(self._same_track(g, h) for g in keep):
                continue
            keep.append(h)
        if not keep:
            keep = [reported]
        keep = keep[: self._config.max_hypotheses]
        # reported hypothesis: keep the current one unless another leads by switch_log_ratio
        if reported in keep:
            lead = max(keep, key=lambda h: float(h.aux[L.A_LOGLIK]))
            margin = self._config.switch_log_ratio
            ahead = float(lead.aux[L.A_LOGLIK]) > float(reported.aux[L.A_LOGLIK]) + margin
            chosen = lead if ahead else reported
        else:
            chosen = max(keep, key=lambda h: float(h.aux[L.A_LOGLIK]))
        if len(keep) == 1:
            keep[0].aux[L.A_LOGLIK] = 0.0  # alone: restart the score so it never drifts
        self._hyps = keep
        self._reported = keep.index(chosen)
