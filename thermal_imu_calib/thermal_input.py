"""The thermal input of a calibration: a stateful first-order lag of each temperature input.

The temperature sensor is not where the error is made: the proof mass and the die follow
the reading with a delay, so heating and cooling legs disagree at the same reading
(hysteresis). ``ThermalFilter`` describes, per temperature input, a first-order lag with
time constant ``tau`` (s); every model family then sees the lagged temperature::

    tau * dT_lag/dt = T - T_lag          (T_lag = T when tau = 0)

To first order ``T_lag = T - tau * dT/dt``: the same thing as a model in temperature and
its rate with one shared coefficient per input, without differentiating a quantised
signal. File section (``temperature.filter``, one tau per input)::

    filter: {kind: lag, tau_s: [300.0], unit: s,
             restart_spread: {accel: {value: [...], unit: m/s^2},    # optional
                              gyro: {value: [...], unit: rad/s}}}

Because the lag has memory, it must run over the whole temperature history: the offline
paths and the live compensator push every batch through one ``ThermalStream`` (via
``CalibrationStream``) before ``Calibration.apply``. A stream starts in equilibrium
(``T_lag = T`` at its first sample), exactly as the estimator assumes at the start of each
recording. ``Calibration.apply`` alone, without a stream, evaluates the models at thermal
equilibrium (``T_lag = T``).

A stream that (re)starts does not know the lagged state it should have: its output may be
off by what the lag changed in the models' output. ``restart_spread`` (per sensor, (3,)
in the sensor's unit; measured on the calibration windows, ``estimation.thermal_lag``)
is the largest such change over the calibration data; the stream reports its age
(``ThermalStream.age_s``) and ``Calibration.apply`` widens the 1-sigma by it, decaying
``exp(-age / tau)`` with each axis' input, as the restarted state's error does. Files
written before it have no ``restart_spread``: no widening.

The discretisation is exact for a temperature that is piecewise linear between samples,
for any (also irregular) sample spacing, so 5-s window means and 200-Hz IMU rows give the
same lagged temperature.
"""

from dataclasses import dataclass
from typing import Optional

import numpy as np

#: largest accepted time constant, s (a day: anything longer is a units mistake)
MAX_TAU_S = 86400.0
#: at window level, a gap longer than this (or time going backwards, as between merged
#: logs) restarts the filter in equilibrium: the temperature history in between is unknown
RESTART_GAP_S = 1800.0
FILTER_KINDS = ('lag',)
#: the sensors a ``restart_spread`` may name, and their units
SPREAD_UNITS = {'accel': 'm/s^2', 'gyro': 'rad/s'}
#: history terms: a reading that moves faster than this (degC/s) plus ``STEP_DEGC`` between
#: two samples is a step of the data (a stale value replaced, a sensor reset), not heat
MAX_RATE_DEGC_S = 1.0
STEP_DEGC = 0.5
#: version of ``CalibrationStream.state`` (what a compensator saves to resume after a restart)
STATE_VERSION = 1


def lag_filter(t, u, tau, state=None):
    """Filter samples ``u`` at times ``t`` (s) by a first-order lag with time constant ``tau``.

    ``state`` is ``(t_last, u_last, y_last)`` from the previous call (None: start in
    equilibrium at the first sample). Returns ``(y, state)``. Vectorised: the linear
    recurrence ``y_i = a_i y_(i-1) + g_i`` is solved by cumulative sums in blocks whose
    total decay stays below e^40, so there is no per-sample Python loop.
    """
    t = np.asarray(t, float)
    u = np.asarray(u, float)
    n = t.shape[0]
    if n == 0:
        return np.zeros(0), state
    if tau <= 0:
        return u.copy(), (float(t[-1]), float(u[-1]), float(u[-1]))
    if state is None:
        state = (float(t[0]), float(u[0]), float(u[0]))
    t_prev, u_prev, y = state
    dt = np.maximum(np.diff(t, prepend=t_prev), 0.0)   # time going backwards: hold
    r = dt / tau
    a = np.exp(-r)
    small = r < 1e-4
    rs = np.where(small, 1.0, r)
    # weight of the new sample for a linear ramp between samples: 1 - (1 - a) / r
    c0 = np.where(small, r / 2 - r * r / 6 + r ** 3 / 24, (r + np.expm1(-r)) / rs)
    g = c0 * u + (1.0 - a - c0) * np.concatenate([[u_prev], u[:-1]])
    big = np.cumsum(r)
    out = np.empty(n)
    start, base = 0, 0.0
    while start < n:
        end = max(int(np.searchsorted(big, base + 40.0, side='right')), start + 1)
        if end == start + 1 and big[start] - base > 40.0:
            out[start] = a[start] * y + g[start]          # one huge step: no exp overflow
        else:
            rel = big[start:end] - base
            out[start:end] = np.exp(-rel) * (y + np.cumsum(np.exp(rel) * g[start:end]))
        y = float(out[end - 1])
        base = float(big[end - 1])
        start = end
    return out, (float(t[-1]), float(u[-1]), y)


@dataclass
class ThermalFilter:
    """Per-input first-order lag turning temperature readings into the models' input."""

    tau_s: np.ndarray
    kind: str = 'lag'
    #: {'accel': (3,) m/s^2, 'gyro': (3,) rad/s} (either may be absent) or None: the
    #: largest change of the output the lag made over the calibration data, how far a
    #: stream (re)started in equilibrium may be off
    restart_spread: Optional[dict] = None

    def __post_init__(self):
        self.tau_s = np.atleast_1d(np.asarray(self.tau_s, float))
        if self.kind not in FILTER_KINDS:
            raise ValueError(f'temperature filter kind {self.kind!r} is not one of '
                             f'{FILTER_KINDS}')
        if self.tau_s.ndim != 1 or not np.all(np.isfinite(self.tau_s)) \
                or np.any(self.tau_s < 0) or np.any(self.tau_s > MAX_TAU_S):
            raise ValueError(f'temperature filter tau_s {self.tau_s.tolist()} must be finite, '
                             f'in 0..{MAX_TAU_S:g} s (one value per temperature input)')
        spread = {}
        for which, v in (self.restart_spread or {}).items():
            if which not in SPREAD_UNITS:
                raise ValueError(f'temperature filter restart_spread names {which!r}; it may '
                                 f'name {tuple(SPREAD_UNITS)}')
            if isinstance(v, dict):
                v = v.get('value')
            if v is None:
                continue
            v = np.asarray(v, float).reshape(-1)
            if v.shape != (3,) or not np.all(np.isfinite(v)) or np.any(v < 0):
                raise ValueError(f'temperature filter restart_spread.{which} {v.tolist()} '
                                 'must be three finite values >= 0 (one per axis)')
            spread[which] = v
        self.restart_spread = spread or None

    @property
    def n_inputs(self):
        """Return the number of temperature inputs the filter expects."""
        return int(self.tau_s.shape[0])

    @property
    def is_identity(self):
        """Return True when every time constant is zero (the reading is the input)."""
        return bool(np.all(self.tau_s == 0))

    def to_dict(self):
        """Return the ``temperature.filter`` file section."""
        d = {'kind': self.kind, 'tau_s': self.tau_s.tolist(), 'unit': 's',
             'description': 'first-order lag per temperature input: the models see '
                            'T_lag with tau dT_lag/dt = T - T_lag'}
        if self.restart_spread:
            d['restart_spread'] = {
                **{k: {'value': v.tolist(), 'unit': SPREAD_UNITS[k]}
                   for k, v in self.restart_spread.items()},
                'description': 'largest |output at T_lag - output at T| over the calibration '
                               'data: a stream restarted in equilibrium widens its 1-sigma '
                               'by it, decaying exp(-age / tau)'}
        return d

    @staticmethod
    def from_dict(d, n_inputs):
        """Parse the file section; raises ValueError naming what is wrong."""
        if not isinstance(d, dict) or 'tau_s' not in d:
            raise ValueError('temperature.filter needs "kind" and "tau_s"')
        if str(d.get('unit', 's')) != 's':
            raise ValueError(f'temperature.filter unit {d.get("unit")!r} must be s')
        spread = d.get('restart_spread') or None
        if spread is not None:
            if not isinstance(spread, dict):
                raise ValueError('temperature.filter.restart_spread must be a mapping of '
                                 f'{" and ".join(SPREAD_UNITS)} to three values each')
            spread = {k: v for k, v in spread.items() if k in SPREAD_UNITS}
        f = ThermalFilter(np.asarray(d['tau_s'], float), str(d.get('kind', 'lag')), spread)
        if f.n_inputs != n_inputs:
            raise ValueError(f'temperature.filter has {f.n_inputs} tau_s for {n_inputs} '
                             'temperature inputs')
        return f

    def stream(self):
        """Return a new ThermalStream holding the filter state (one per IMU stream)."""
        return ThermalStream(self)

    def window_temperatures(self, windows):
        """Return the (m, k) lagged mean temperature of each window, degC.

        Windows are taken in time order at their mid times; the filter restarts in
        equilibrium where time goes backwards or a gap exceeds ``RESTART_GAP_S``.
        """
        return lag_windows(windows.t0, windows.t1, windows.temp, self.tau_s)


def lag_windows(t0, t1, temp, tau_s):
    """Lag (m, k) window temperatures at window mid times (see ThermalFilter)."""
    temp = np.asarray(temp, float)
    out = temp.copy()
    if temp.shape[0] == 0:
        return out
    tm = 0.5 * (np.asarray(t0, float) + np.asarray(t1, float))
    order = np.argsort(tm, kind='stable')
    ts = tm[order]
    gaps = np.flatnonzero(np.diff(ts) > RESTART_GAP_S) + 1
    bounds = np.concatenate([[0], gaps, [len(ts)]])
    for j, tau in enumerate(np.broadcast_to(np.asarray(tau_s, float), (temp.shape[1],))):
        col = temp[order, j]
        res = np.empty_like(col)
        for a, b in zip(bounds[:-1], bounds[1:]):
            res[a:b], _ = lag_filter(ts[a:b], col[a:b], float(tau))
        out[order, j] = res
    return out


class ThermalStream:
    """The running state of a ThermalFilter over one temperature stream."""

    def __init__(self, thermal_filter):
        self.filter = thermal_filter
        self._state = None
        self._t_start = None

    def reset(self):
        """Forget the history: the next sample starts in equilibrium."""
        self._state = None
        self._t_start = None

    def age_s(self, t):
        """Return (n,) seconds since the stream (re)started at times ``t`` (0 before it)."""
        t = np.asarray(t, float)
        if self._t_start is None:
            return np.zeros(t.shape)
        return np.maximum(t - self._t_start, 0.0)

    def push(self, t, temps):
        """Return the (n, k) model-input temperatures for readings ``temps`` at times ``t`` (s).

        Rows must be in time order within and across calls; a step back in time holds
        the state.
        """
        temps = np.asarray(temps, float)
        t = np.asarray(t, float)
        k = self.filter.n_inputs
        if temps.ndim != 2 or temps.shape[1] != k or t.shape != (temps.shape[0],):
            raise ValueError(f'need (n,) times and (n, {k}) temperatures, got {t.shape} and '
                             f'{temps.shape}')
        if not np.all(np.isfinite(temps)):
            raise ValueError('temperature contains NaN/Inf; resolve missing samples first '
                             '(the lag filter would carry it forever)')
        if len(t) == 0:
            return temps.copy()
        if self._t_start is None:
            self._t_start = float(t[0])
        out = np.empty_like(temps)
        states = self._state or [None] * k
        new = []
        for j in range(k):
            out[:, j], st = lag_filter(t, temps[:, j], float(self.filter.tau_s[j]), states[j])
            new.append(st)
        self._state = new
        return out

    def state(self):
        """Return the running state as plain types (None before the first sample)."""
        if self._state is None:
            return None
        return {'t_start': self._t_start, 'filters': [list(st) for st in self._state]}

    def restore(self, state):
        """Continue from ``state()`` of a stream of the same filter (ValueError if not)."""
        if state is None:
            self.reset()
            return
        filters = state.get('filters')
        if not isinstance(filters, list) or len(filters) != self.filter.n_inputs or not all(
                isinstance(f, list) and len(f) == 3 for f in filters):
            raise ValueError(f'the saved lag state has {len(filters or [])} inputs, the '
                             f'filter {self.filter.n_inputs}')
        self._state = [tuple(float(v) for v in f) for f in filters]
        self._t_start = float(state['t_start'])


class CalibrationStream:
    """Apply a Calibration batch after batch, carrying the thermal filter state.

    One per compensated IMU stream: ``apply(t, accel, gyro, temps)`` with stamps in s and
    raw temperature readings; without a filter in the calibration it is ``apply`` itself.
    """

    def __init__(self, calibration):
        self.calibration = calibration
        f = getattr(calibration, 'temperature_filter', None)
        self.thermal = None if f is None or f.is_identity else f.stream()
        keys = [k for m in (getattr(calibration, 'accel', None),
                            getattr(calibration, 'gyro', None))
                for k in getattr(m, 'history_keys', ())]
        n_inputs = len(getattr(calibration, 'inputs', ()) or ())
        self.history = HistoryStream(keys, n_inputs) if keys and n_inputs else None

    def model_temperatures(self, t, temps):
        """Return the models' input temperatures for raw readings (advances the state)."""
        temps = np.asarray(temps, float)
        if self.thermal is None or temps.ndim != 2 or temps.shape[1] == 0:
            return temps
        return self.thermal.push(t, temps)

    def apply(self, t, accel, gyro, temps=None):
        """Compensate one batch (rows in time order, t in s); returns ``Compensated``.

        With a filter the calibration also gets the filter's age (``filter_age``): its
        1-sigma covers the restart (``ThermalFilter.restart_spread``). With a gyro ageing
        term it gets the stamps (``Calibration.gyro_ageing``).
        """
        history, extra = None, {}
        if temps is not None:
            temps = np.asarray(temps, float).reshape(len(t), -1)
            if self.history is not None:
                history = self.history.push(t, temps)
            temps = self.model_temperatures(t, temps)
            if self.thermal is not None and temps.shape[1]:
                extra['filter_age'] = self.thermal.age_s(t)
        if history is not None:
            extra['history'] = history
        if getattr(self.calibration, 'gyro_ageing', None):
            extra['stamps'] = t     # the gyro bias carried to the samples' time
        return self.calibration.apply(accel, gyro, temps, **extra)

    def reset(self):
        """Restart the filter in equilibrium (e.g. after a long temperature dropout)."""
        if self.thermal is not None:
            self.thermal.reset()
        if self.history is not None:
            self.history.reset()

    def state(self):
        """Return the thermal-history state as plain types (JSON), or None when stateless.

        ``t_last``: the stamp (s) of the newest sample pushed (None before the first). A new
        stream of the same calibration continues from it with ``restore``: a compensator
        restarted within the models' memory then needs no restart widening and makes no
        restart step (the gap is run through like any gap, ``lag_filter``).
        """
        if self.thermal is None and self.history is None:
            return None
        th = None if self.thermal is None else self.thermal.state()
        hi = None if self.history is None else self.history.state()
        stamps = [f[0] for f in (th or {}).get('filters', [])]
        stamps += [hi['last_t']] if hi is not None else []
        return {'version': STATE_VERSION, 't_last': max(stamps) if stamps else None,
                'thermal': th, 'history': hi}

    def restore(self, state):
        """Continue from ``state()`` of a stream of the same calibration.

        Raises ValueError (saying what differs) when the state does not fit this
        calibration's filter or history terms; the stream is then unchanged.
        """
        if not isinstance(state, dict) or state.get('version') != STATE_VERSION:
            raise ValueError(f'not a stream state of version {STATE_VERSION}')
        if (state.get('thermal') is not None) != (self.thermal is not None) or \
                (state.get('history') is not None) != (self.history is not None):
            raise ValueError('the saved state has other thermal terms than this calibration')
        if self.history is not None:
            self.history.check_state(state['history'])
        if self.thermal is not None:
            self.thermal.restore(state['thermal'])
        if self.history is not None:
            self.history.restore(state['history'])


# ---------------------------------------------------------------------- history terms
def history_key(taus):
    """Return the name of a cascade of first-order lags, e.g. 'lag:50' or 'lag:20:200' (s)."""
    return 'lag:' + ':'.join(f'{float(t):g}' for t in taus)


def parse_history_key(key):
    """Return the tuple of time constants (s) of a ``history_key``; ValueError if malformed."""
    parts = str(key).split(':')
    if parts[0] != 'lag' or len(parts) < 2:
        raise ValueError(f'history term {key!r} must look like lag:TAU or lag:TAU1:TAU2 (s)')
    taus = tuple(float(p) for p in parts[1:])
    if not all(np.isfinite(t) and 0 < t <= MAX_TAU_S for t in taus):
        raise ValueError(f'history term {key!r}: time constants must be in (0, {MAX_TAU_S:g}] s')
    return taus


def history_windows(t0, t1, temp, taus):
    """Return the (m, k) window temperatures through a cascade of first-order lags ``taus``.

    One lag is ``lag_windows``; two (die-to-case two-state lag) feed the first state into
    the second. Same restarts as ``lag_windows``.
    """
    out = np.asarray(temp, float)
    for tau in taus:
        out = lag_windows(t0, t1, out, float(tau))
    return out


class HistoryStream:
    """Running states of the lag cascades a history-dependent model needs, per input.

    ``push(t, temps)`` returns ``{key: (n, k)}`` lagged readings for each key
    (``history_key``) and ``'_age_s'``: (n,) seconds since the stream (re)started.

    * Start / restart (``reset``): every state at the first reading (equilibrium), so the
      history terms start at zero; the model's ``predict_std`` widens by what the unknown
      history may hold, decaying with the lags' memory (``models.hysteresis``).
    * A gap: the states run through the temperature interpolated over the gap (a
      physical history: continuous output).
    * A step in the reading faster than ``MAX_RATE_DEGC_S`` (plus ``STEP_DEGC``), as when
      a held (stale) temperature snaps to the live one, is not a thermal history: the
      states move with the reading, so the history terms keep their value through it.
    """

    def __init__(self, keys, n_inputs):
        self.keys = list(dict.fromkeys(keys))
        self.taus = {k: parse_history_key(k) for k in self.keys}
        self.n_inputs = int(n_inputs)
        self.reset()

    def reset(self):
        """Forget the history: the next sample starts in equilibrium."""
        self._state = {}
        self._last = None          # (t, (k,) reading) of the previous sample
        self._offset = None        # (k,) summed reading steps removed from the history
        self._t_start = None

    def _continuous(self, t, temps):
        """Return the readings with implausible steps removed and the (n, k) removed sum."""
        if self._last is None:
            t_prev, u_prev = t[0], temps[0]
            self._offset = np.zeros(temps.shape[1])
        else:
            t_prev, u_prev = self._last
        d = np.diff(temps, axis=0, prepend=u_prev[None, :])
        dt = np.maximum(np.diff(t, prepend=t_prev), 0.0)
        step = np.abs(d) > STEP_DEGC + MAX_RATE_DEGC_S * dt[:, None]
        off = self._offset + np.cumsum(np.where(step, d, 0.0), axis=0)
        self._last = (float(t[-1]), temps[-1].copy())
        self._offset = off[-1].copy()
        return temps - off, off

    def push(self, t, temps):
        """Return {key: (n, k) lagged readings, '_age_s': (n,)}; rows in time order."""
        t = np.asarray(t, float)
        temps = np.asarray(temps, float).reshape(len(t), -1)
        if not np.all(np.isfinite(temps)):
            raise ValueError('temperature contains NaN/Inf; resolve missing samples first '
                             '(the history terms would carry it forever)')
        if len(t) == 0:
            return {**{k: temps.copy() for k in self.keys}, '_age_s': np.zeros(0)}
        if self._t_start is None:
            self._t_start = float(t[0])
        smooth, off = self._continuous(t, temps)
        out = {'_age_s': np.maximum(t - self._t_start, 0.0)}
        for key in self.keys:
            u = smooth
            states = self._state.get(key) or [[None] * temps.shape[1] for _ in self.taus[key]]
            new = []
            for s, tau in enumerate(self.taus[key]):
                y = np.empty_like(u)
                row = []
                for j in range(u.shape[1]):
                    y[:, j], st = lag_filter(t, u[:, j], tau, states[s][j])
                    row.append(st)
                new.append(row)
                u = y
            self._state[key] = new
            out[key] = u + off
        return out

    def state(self):
        """Return the cascades' states as plain types (None before the first sample)."""
        if self._last is None:
            return None
        return {'keys': list(self.keys), 'n_inputs': self.n_inputs, 't_start': self._t_start,
                'last_t': self._last[0], 'last_u': self._last[1].tolist(),
                'offset': self._offset.tolist(),
                'states': {k: [[list(st) for st in row] for row in v]
                           for k, v in self._state.items()}}

    def check_state(self, state):
        """Raise ValueError when ``state`` is not one of these cascades (None is)."""
        if state is None:
            return
        if state.get('keys') != self.keys or state.get('n_inputs') != self.n_inputs:
            raise ValueError(f'the saved history terms {state.get("keys")} x '
                             f'{state.get("n_inputs")} inputs differ from this calibration\'s '
                             f'{self.keys} x {self.n_inputs}')

    def restore(self, state):
        """Continue from ``state()`` of the same cascades (``check_state`` first)."""
        self.check_state(state)
        if state is None:
            self.reset()
            return
        self._t_start = float(state['t_start'])
        self._last = (float(state['last_t']), np.asarray(state['last_u'], float))
        self._offset = np.asarray(state['offset'], float)
        self._state = {k: [[tuple(float(v) for v in st) for st in row] for row in rows]
                       for k, rows in state['states'].items()}
