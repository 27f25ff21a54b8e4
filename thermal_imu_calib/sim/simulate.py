"""Realistic IMU recordings with temperature-induced errors, for demos, tests and benchmarks.

A scenario is a ``ScenarioConfig`` in ``SCENARIOS``; ``simulate(name, seed)`` turns it into a
``SimRecording`` that streams ``ImuColumns`` chunks (bounded memory, any length) and holds
the temperature series, the pose schedule, the true calibration and the lab prior.

Randomness has two independent sources:

* the *device* (true thermal parameters, lab prior, per-sensor warm-up shape) is drawn
  from ``(seed, device family)``, so ``nav-coldstart`` and ``nav-validation`` with the same
  seed are two cold starts of one and the same IMU;
* the *recording* (noise, hold schedule, tilts, headings, hand motion, start temperature,
  temperature sample phase) is drawn from ``(seed, scenario name)``.

Physics (body frame = accelerometer reference frame p, navigation frame ENU):

* accelerometer, seed 000 eq. (8), written out here independently of ``models.field``::

      raw_i = b0_i + db0_i + b1_i dT_i + b2_i dT_i^2
              + (k0_i + dk0_i + k1_i dT_i + k2_i dT_i^2) (S f^p)_i + noise,   dT_i = T_i - T0_i

  with f^p = C_nb^T (a^n - g^n) the specific force (gravity rotating during pose changes,
  plus the hand's translational acceleration);
* gyro, seed 002 eq. (3)-(4) written forward: raw = M w^b + G f^p + sum_j c_j dT^j + noise
  with w^b = w_nb^b + C_nb^T w_ie^n (earth rate at the configured latitude), M = I +
  scale errors + misalignment (3x3), G the g-sensitivity (rad/s per m/s^2); the 'nav'
  family has M = I, G = 0;
* temperature: per sensor a first-order warm-up T = T_amb + rise (1 - exp(-t / tau)) or a
  chamber cycle; the error is driven by the sensor reading itself or, with ``lag_s > 0``, by
  a first-order lagged copy of it (hysteresis between heating and cooling legs). Published
  readings are quantised and asynchronous to the IMU.

White noise per sample is density * sqrt(rate) (one-sided density in unit/sqrt(Hz)).
"""

import dataclasses
import os
import time
from dataclasses import dataclass, field
from typing import Dict, List, Optional

import numpy as np
import yaml

from ..calibration import Calibration, TemperatureInput
from ..thermal_input import ThermalFilter
from ..gravity import normal_gravity
from ..io.columns import ImuColumns, TemperatureColumns
from ..models.field import FieldPolynomialModel

from .scenarios import SCENARIOS as _MORE  # noqa: E402 (needs ScenarioConfig above)

from .devices import (_rng, accel_forward, DEG, DeviceParams,  # noqa: F401  (re-exported)
                      DEVICES, DeviceSpec, draw_device, EARTH_RATE, G0, gyro_forward,
                      THERMAL_COLUMNS)
from .schedule import (_build_schedule, _kinematics, _Segments,  # noqa: F401  (re-exported)
                       _thermal_track, _ThermalTrack, FACES, first_order_lag, Hold,
                       ScenarioConfig, SCENARIOS, SIX_FACES, TILTED)


#: 2025-01-01T00:00:00Z; recordings start within 30 days of it
EPOCH_NS = 1_735_689_600 * 10 ** 9


# ---------------------------------------------------------------------------------- recording
@dataclass
class TruthChunk:
    """The noise-free truth behind one IMU chunk (for benchmarks and tests)."""

    stamp_ns: np.ndarray
    specific_force: np.ndarray   # (n, 3) m/s^2, sensor frame p
    angular_rate: np.ndarray     # (n, 3) rad/s, incl. earth rate
    temps: np.ndarray            # (n, k) degC, the error-driving temperature per input


@dataclass
class SimRecording:
    """A simulated recording: lazily generated IMU chunks plus everything known about it."""

    config: ScenarioConfig
    seed: int
    device: DeviceParams
    truth: Calibration
    prior: Calibration
    schedule: List[Hold]
    temperatures: Dict[str, TemperatureColumns]
    gravity: float
    start_ns: int
    duration: float
    n_samples: int
    meta: dict = field(default_factory=dict)
    imu_topic: str = '/imu/data_raw'
    frame_id: str = 'imu_link'
    _segments: Optional[_Segments] = field(default=None, repr=False)
    _thermal: Optional[_ThermalTrack] = field(default=None, repr=False)
    #: errors outside the model families (``sim.unmodelled``): ``fn(TruthChunk)`` returns
    #: (accel (n, 3) m/s^2, gyro (n, 3) rad/s) added to the raw output before quantisation
    extra_error: Optional[object] = field(default=None, repr=False)

    @property
    def name(self):
        """Return the scenario name."""
        return self.config.name

    @property
    def imu_rate(self):
        """Return the IMU sample rate in Hz."""
        return self.config.imu_rate

    @property
    def accel_noise_std(self):
        """Return the white accel noise 1-sigma per sample (3,), m/s^2, incl. quantisation."""
        return self.truth.accel_noise_std

    @property
    def gyro_noise_std(self):
        """Return the white gyro noise 1-sigma per sample (3,), rad/s, incl. quantisation."""
        return self.truth.gyro_noise_std

    def stamps(self, i0=0, i1=None):
        """Return the int64 ns IMU stamps of samples i0..i1."""
        i1 = self.n_samples if i1 is None else i1
        i = np.arange(i0, i1, dtype=np.int64)
        return self.start_ns + np.round(i * (1e9 / self.imu_rate)).astype(np.int64)

    def temperature_at(self, stamp_ns, which='drive'):
        """Return the exact (n, k) temperature per input at IMU stamps.

        ``which='drive'`` is the temperature the errors follow (the lagged one when the
        scenario has ``lag_s``), ``'read'`` what the sensor sees before quantisation.
        """
        t = (np.asarray(stamp_ns, np.int64) - self.start_ns) * 1e-9
        return self._thermal.at(t, which)

    def _ranges(self, chunk_size):
        step = int(chunk_size or self.config.chunk_size)
        return [(i, min(i + step, self.n_samples)) for i in range(0, self.n_samples, step)]

    def truth_chunks(self, chunk_size=None):
        """Yield ``TruthChunk`` aligned with ``imu_chunks`` (same chunk_size)."""
        lat = self.config.latitude * DEG
        w_ie = EARTH_RATE * np.array([0.0, np.cos(lat), np.sin(lat)])
        for i0, i1 in self._ranges(chunk_size):
            stamp = self.stamps(i0, i1)
            t = (stamp - self.start_ns) * 1e-9
            f_b, w_b = _kinematics(self._segments, t, self.gravity, w_ie)
            yield TruthChunk(stamp, f_b, w_b, self._thermal.at(t, 'drive'))

    def imu_chunks(self, chunk_size=None):
        """Yield the raw IMU recording as ``ImuColumns`` chunks (deterministic per seed).

        The noise stream does not depend on ``chunk_size``; each call starts afresh.
        """
        spec = self.device.spec
        rng = _rng(self.seed, 'recording', self.config.name, 'imu-noise')
        sig_a = spec.accel_noise_density * np.sqrt(self.imu_rate)
        sig_g = spec.gyro_noise_density * np.sqrt(self.imu_rate)
        dev, cal = self.device, self.truth
        for tc in self.truth_chunks(chunk_size):
            n = tc.stamp_ns.shape[0]
            noise = rng.standard_normal((n, 6))
            ta = tc.temps[:, cal.accel_input]
            tg = tc.temps[:, cal.gyro_input]
            acc = accel_forward(tc.specific_force, ta, dev.t0, dev.k0, dev.b0, dev.s,
                                dev.thermal) + sig_a * noise[:, :3]
            gyr = gyro_forward(tc.angular_rate, tg, dev.t0, dev.gyro_coeffs, dev.gyro_m,
                               dev.gyro_g, tc.specific_force) + sig_g * noise[:, 3:]
            if self.config.tremor_dps > 0:
                from .scenarios import tremor
                acc, gyr = tremor(self, tc, acc, gyr)
            if self.extra_error is not None:
                da, dg = self.extra_error(tc)
                acc, gyr = acc + da, gyr + dg
            if spec.accel_lsb > 0:
                acc = np.round(acc / spec.accel_lsb) * spec.accel_lsb
            if spec.gyro_lsb > 0:
                gyr = np.round(gyr / spec.gyro_lsb) * spec.gyro_lsb
            yield ImuColumns(tc.stamp_ns, acc, gyr, self.frame_id)

    def imu(self):
        """Return the whole recording as one ``ImuColumns`` (only for short scenarios)."""
        return ImuColumns.concat(list(self.imu_chunks()))

    def summary(self):
        """Return a plain dict describing the recording."""
        return {
            'scenario': self.name, 'seed': self.seed, 'device': self.device.spec.name,
            'duration_s': round(float(self.duration), 3), 'imu_rate_hz': self.imu_rate,
            'imu_samples': self.n_samples, 'imu_topic': self.imu_topic,
            'holds': len(self.schedule),
            'temperature': {topic: {'samples': len(tc),
                                    'min': float(tc.temperature.min()),
                                    'max': float(tc.temperature.max())}
                            for topic, tc in self.temperatures.items()},
            'temperature_lag_s': float(self.config.lag_s),
        }

    def schedule_dict(self):
        """Return the schedule file content (metadata + holds) as plain types."""
        cfg = self.config
        return {
            'scenario': self.name, 'seed': self.seed, 'description': cfg.description,
            'imu_topic': self.imu_topic, 'frame_id': self.frame_id,
            'imu_rate_hz': float(cfg.imu_rate), 'imu_samples': int(self.n_samples),
            'start_stamp_ns': int(self.start_ns), 'duration_s': float(self.duration),
            'gravity': float(self.gravity), 'latitude_deg': float(cfg.latitude),
            'up_convention': 'up = unit specific force at rest in the sensor frame '
                             '(= -gravity direction)',
            'temperature': {'topics': list(cfg.temp_topics), 'rate_hz': float(cfg.temp_rate),
                            'lsb_degC': float(cfg.temp_lsb), 'noise_degC': float(cfg.temp_noise),
                            'lag_s': float(cfg.lag_s)},
            'simulation': _plain(self.meta),
            'holds': [h.to_dict() for h in self.schedule],
        }


def _plain(d):
    out = {}
    for k, v in d.items():
        if isinstance(v, np.ndarray):
            out[k] = v.tolist()
        elif isinstance(v, np.generic):
            out[k] = v.item()
        else:
            out[k] = v
    return out


def _config(name, overrides):
    cfg = name if isinstance(name, ScenarioConfig) else SCENARIOS.get(name)
    if cfg is None:
        raise KeyError(f'unknown scenario {name!r}; known: {", ".join(SCENARIOS)}')
    if overrides:
        cfg = dataclasses.replace(cfg, **overrides)
    if cfg.device not in DEVICES:
        raise ValueError(f'unknown device family {cfg.device!r}; known: {sorted(DEVICES)}')
    if cfg.profile == 'cycle' and cfg.repetitions * len(cfg.faces) != 1:
        raise ValueError('a chamber cycle is recorded in one pose: use one face, 1 repetition')
    if len(cfg.temp_topics) not in (1, 3):
        raise ValueError('temp_topics must be one shared topic or three per-axis topics')
    return cfg


def simulate(name, seed=0, **overrides):
    """Build the recording of scenario ``name`` (a ``SCENARIOS`` key or a ScenarioConfig).

    ``overrides`` replace config fields (e.g. ``repetitions=1`` for a short test run).
    Temperatures, schedule and calibrations are computed now; IMU samples only when
    ``imu_chunks()`` is iterated.
    """
    cfg = _config(name, overrides)
    seed = int(seed)
    dev = draw_device(cfg.device, seed)
    spec = dev.spec
    rec_rng = _rng(seed, 'recording', cfg.name, 'schedule')
    seg, hold_info, duration = _build_schedule(cfg, rec_rng)
    env = _rng(seed, 'recording', cfg.name, 'environment')
    t_amb = cfg.t_amb + env.uniform(-cfg.t_amb_jitter, cfg.t_amb_jitter)
    start_ns = EPOCH_NS + int(env.integers(0, 30 * 86400)) * 10 ** 9 \
        + int(env.integers(0, 10 ** 9 // 1000)) * 1000
    rate = float(cfg.imu_rate)
    n = int(np.floor(duration * rate)) + 1
    thermal = _thermal_track(cfg, dev, duration, t_amb)
    gravity = normal_gravity(cfg.latitude)

    # published temperature readings: asynchronous, noisy, quantised
    k = len(cfg.temp_topics)
    temps = {}
    period = 1.0 / cfg.temp_rate
    for i, topic in enumerate(cfg.temp_topics):
        tt = env.uniform(0, period) + np.arange(0.0, duration, period)
        tt = tt[tt <= duration]
        val = thermal.at(tt, 'read')[:, i] + cfg.temp_noise * env.standard_normal(tt.size)
        if cfg.temp_lsb > 0:
            val = np.round(np.round(val / cfg.temp_lsb) * cfg.temp_lsb, 9)
        temps[topic] = TemperatureColumns(start_ns + np.round(tt * 1e9).astype(np.int64),
                                          val, 'imu_link')

    idx = [0, 1, 2] if k == 3 else [0, 0, 0]
    inputs = [TemperatureInput(f't_{t.rstrip("/").split("/")[-1]}' if k == 3 else 't0', t)
              for t in cfg.temp_topics]
    valid = np.array([[temps[t].temperature.min(), temps[t].temperature.max()]
                      for t in cfg.temp_topics])
    sig_a = np.sqrt((spec.accel_noise_density ** 2 * rate) + spec.accel_lsb ** 2 / 12)
    sig_g = np.sqrt((spec.gyro_noise_density ** 2 * rate) + spec.gyro_lsb ** 2 / 12)
    meta = {'scenario': cfg.name, 'seed': seed, 'device': spec.name,
            'temperature_profile': cfg.profile, 'temperature_lag_s': float(cfg.lag_s),
            'accel_noise_density': spec.accel_noise_density,
            'gyro_noise_density': spec.gyro_noise_density,
            'accel_lsb': spec.accel_lsb, 'gyro_lsb': spec.gyro_lsb}
    if cfg.profile == 'warmup':
        meta.update(ambient_degC=round(float(t_amb), 4),
                    warmup_rise_degC=(cfg.rise * dev.rise_factor[:k]).round(4).tolist(),
                    warmup_tau_s=(cfg.tau_s * dev.tau_factor[:k]).round(2).tolist())
    else:
        meta.update(chamber_degC=[cfg.cycle_lo, cfg.cycle_hi], cycles=cfg.cycles,
                    ramp_degC_per_min=cfg.ramp_degc_per_min, dwell_s=cfg.dwell_s,
                    case_tau_s=(cfg.case_tau_s * dev.tau_factor[:k]).round(2).tolist())
    notes = [f'simulated truth: scenario {cfg.name}, seed {seed}, device {spec.name} '
             f'({spec.description})']
    if cfg.lag_s > 0:
        notes.append(f'the simulated errors follow the temperature reading through a '
                     f'first-order lag of {cfg.lag_s:g} s; this polynomial is in the lagged '
                     'temperature')
    if spec.prior == 'nominal':
        notes.append('the prior is nominal (k0 = 1, b0 = 0, S = I); the true S is skewed')
    if not dev.gyro_ideal:
        notes.append('gyro: seed 002 form with scale/misalignment Omega1 = M^-1 and '
                     'g-sensitivity C = -M^-1 G (rad/s per m/s^2)')
    truth = Calibration(
        accel=FieldPolynomialModel(dev.t0, dev.thermal, dev.k0, dev.b0, dev.s),
        gyro=dev.gyro_truth_model(),
        inputs=inputs, valid_range=valid, accel_input=idx, gyro_input=idx,
        frame_id='imu_link', gravity=gravity,
        gravity_source=f'WGS84 normal gravity at {cfg.latitude} deg, 0 m',
        accel_noise_std=np.full(3, sig_a), gyro_noise_std=np.full(3, sig_g),
        fit={'method': 'simulation truth', 'simulation': meta}, notes=notes,
        temperature_filter=ThermalFilter(np.full(k, cfg.lag_s)) if cfg.lag_s > 0 else None)
    lo = np.array([dev.t0[[a for a in range(3) if idx[a] == i]].min() - 0.5 for i in range(k)])
    hi = np.array([dev.t0[[a for a in range(3) if idx[a] == i]].max() + 0.5 for i in range(k)])
    prior = Calibration(
        accel=FieldPolynomialModel(dev.t0, np.zeros((3, 6)), dev.prior_k0, dev.prior_b0,
                                   dev.prior_s),
        inputs=list(inputs), valid_range=np.stack([lo, hi], 1), accel_input=idx,
        frame_id='imu_link', gravity=gravity, gravity_source=truth.gravity_source,
        fit={'method': 'lab calibration (simulated)' if spec.prior == 'lab'
             else 'nominal (no lab calibration)', 'simulation': meta},
        notes=[f'prior of simulated device {spec.name} seed {seed}: k0, b0, S at T0, no '
               'thermal terms; valid only near the lab temperature T0'])

    schedule = [Hold(i, label, t0, t1, start_ns + int(round(t0 * 1e9)),
                     start_ns + int(round(t1 * 1e9)), up, tilt, heading)
                for i, (label, t0, t1, up, tilt, heading) in enumerate(hold_info)]
    return SimRecording(cfg, seed, dev, truth, prior, schedule, temps, gravity, start_ns,
                        duration, n, meta, _segments=seg, _thermal=thermal)


def _sidecar(output, kind):
    return f'{os.fspath(output).rstrip(os.sep)}.{kind}.yaml'


def sidecar_outputs(output, proxy=False):
    """Return [(path, kind, own)] of the side files ``write_scenario`` writes next to a log.

    ``own`` tells an existing file of that kind (``io.output.Outputs.file``).
    """
    from ..io.output import CALIBRATION, containing
    out = [(_sidecar(output, 'truth'), 'calibration file', CALIBRATION),
           (_sidecar(output, 'prior'), 'calibration file', CALIBRATION),
           (_sidecar(output, 'schedule'), 'simulation schedule',
            containing(b'up_convention:'))]
    if proxy:
        out.append((_sidecar(output, 'truth_proxy'), 'calibration file', CALIBRATION))
    return out


def write_scenario(output, name, seed=0, storage='mcap', overwrite=False, compression='none',
                   transform=None, **overrides):
    """Simulate ``name`` and write the bag plus truth, prior and schedule files.

    ``output`` ending in ``.mcap`` becomes a bare MCAP file, anything else a rosbag2
    directory with the given storage ('mcap' or 'sqlite3'); the side files are
    ``<output>.truth.yaml``, ``<output>.prior.yaml`` and ``<output>.schedule.yaml``.
    ``compression='zstd'`` shrinks the log ~8x for ~50% more write time; ``overrides`` are
    passed to ``simulate``; ``transform`` (SimRecording -> SimRecording, e.g.
    ``sim.proxy.with_resonance_proxy``) edits the recording before it is written. Returns
    the paths and a summary dict.
    """
    from ..io.bag_writer import write_columns
    from ..io.output import remove_quietly, staging_dir, write_atomic

    t_start = time.perf_counter()
    rec = simulate(name, seed, **overrides)
    if transform is not None:
        rec = transform(rec)
    out = os.fspath(output).rstrip(os.sep)
    parent = os.path.dirname(os.path.abspath(out))
    os.makedirs(parent, exist_ok=True)
    cfg = rec.config
    var = cfg.temp_noise ** 2 + cfg.temp_lsb ** 2 / 12
    var = {t: rec.meta.get('temperature_variance', {}).get(t, var) for t in rec.temperatures}
    if overwrite and os.path.lexists(out):
        remove_quietly(out)
    with staging_dir(out) as tmp:   # complete or absent, also when interrupted
        counts = write_columns(tmp, rec.imu_topic, rec.imu_chunks(), rec.temperatures,
                               storage=storage, compression=compression,
                               temperature_variance=var)
    paths = {'bag': out, 'truth': _sidecar(out, 'truth'), 'prior': _sidecar(out, 'prior'),
             'schedule': _sidecar(out, 'schedule')}
    rec.truth.save(paths['truth'])
    rec.prior.save(paths['prior'])
    write_atomic(paths['schedule'], yaml.safe_dump(rec.schedule_dict(), sort_keys=False,
                                                   default_flow_style=None, width=100))
    summary = rec.summary()
    summary['messages'] = counts
    summary['seconds'] = round(time.perf_counter() - t_start, 3)
    return {**paths, 'summary': summary}


def still_noise(n, rate_hz, density, random_walk=0.0, seed=0):
    """Return (n, 3) white noise plus a random-walk bias, as a still sensor's error.

    ``density`` N is the one-sided white-noise density (unit/sqrt(Hz): per-sample std
    N sqrt(rate)); ``random_walk`` K is the bias random walk (unit/s/sqrt(Hz): the bias
    moves by K sqrt(dt) per sample). Scalars or per-axis (3,) values. The Allan variance
    of the result is N^2/tau + K^2 tau/3 (IEEE 952), what ``estimation.allan`` reads back.
    """
    rng = np.random.default_rng(seed)
    dt = 1.0 / float(rate_hz)
    white = rng.standard_normal((n, 3)) * (np.asarray(density, float) / np.sqrt(dt))
    walk = np.cumsum(rng.standard_normal((n, 3)), axis=0) * (
        np.asarray(random_walk, float) * np.sqrt(dt))
    return white + walk


SCENARIOS.update(_MORE)
