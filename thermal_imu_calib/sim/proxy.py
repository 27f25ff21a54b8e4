"""A gyro thermal proxy for simulated recordings: the drive-mode resonance frequency.

Seed 002 drives the gyro model by the resonance frequency of the gyro's drive mode instead of
a temperature: the frequency follows the resonator's own temperature (no sensor-to-die
lag) and a frequency counter resolves it far more finely than a die-temperature ADC. Here::

    f = f0 + kf * T_gyro + noise,    quantised to ``lsb_hz``

with ``T_gyro`` the temperature the simulated gyro errors follow (the lagged one in lag
scenarios), typical MEMS/quartz values f0 = 25 kHz at 0 degC and kf = -1.5 Hz/degC, published
asynchronously at ``rate_hz`` as sensor_msgs/Temperature on its own topic (the value in the
``temperature`` field, unit Hz declared by the user). The IMU data do not change: the proxy
is one more thermal input of the same recording.

``with_resonance_proxy(rec)`` adds the topic to a ``sim.SimRecording``;
``proxy_truth(rec)`` is the true calibration with the gyro mapped to the proxy (the same
physics as ``rec.truth``, its bias polynomial re-expressed in Hz); ``write_proxy_scenario``
writes the bag, the usual side files and ``<output>.truth_proxy.yaml``. CLI:
``thermal-imu-calib simulate OUT --scenario NAME --gyro-proxy``.
"""

import dataclasses
from dataclasses import dataclass
import zlib

import numpy as np

from .simulate import write_scenario
from ..calibration import TemperatureInput
from ..io.columns import TemperatureColumns
from ..models.polynomial import OffsetPolynomialModel
from ..models.whole_unit import WholeUnitGyroModel
from ..thermal_input import ThermalFilter


@dataclass(frozen=True)
class ResonanceProxy:
    """How the simulated resonance frequency is made and published (Hz, s)."""

    topic: str = '/imu/gyro_resonance'
    f0_hz: float = 25000.0           # frequency at 0 degC
    kf_hz_per_degc: float = -1.5     # temperature coefficient
    rate_hz: float = 10.0            # publication rate
    lsb_hz: float = 0.01             # frequency-counter resolution
    noise_hz: float = 0.005          # white noise of one reading, 1 sigma

    def frequency(self, temp):
        """Return the noise-free resonance (Hz) at gyro temperatures ``temp`` (degC)."""
        return self.f0_hz + self.kf_hz_per_degc * np.asarray(temp, float)


def _gyro_column(rec):
    idx = set(rec.truth.gyro_input)
    if len(idx) != 1:
        raise ValueError(f'scenario {rec.name} drives the gyro axes by different temperature '
                         f'inputs {rec.truth.gyro_input}; one resonance proxy cannot stand for '
                         'them (use a scenario with one die temperature, e.g. mems-coldstart)')
    return idx.pop()


def with_resonance_proxy(rec, proxy=ResonanceProxy()):
    """Return ``rec`` with the proxy topic added to its temperatures (deterministic per seed)."""
    if proxy.topic in rec.temperatures:
        raise ValueError(f'{proxy.topic} is already a topic of the recording')
    if proxy.kf_hz_per_degc == 0 or proxy.rate_hz <= 0 or proxy.lsb_hz < 0:
        raise ValueError('the proxy needs kf != 0 Hz/degC, rate > 0 Hz and lsb >= 0 Hz')
    col = _gyro_column(rec)
    rng = np.random.default_rng([int(rec.seed), zlib.crc32(f'{rec.name}/gyro-proxy'.encode())])
    period = 1.0 / proxy.rate_hz
    tt = rng.uniform(0, period) + np.arange(0.0, rec.duration, period)
    tt = tt[tt <= rec.duration]
    stamps = rec.start_ns + np.round(tt * 1e9).astype(np.int64)
    f = proxy.frequency(rec.temperature_at(stamps, 'drive')[:, col])
    f = f + proxy.noise_hz * rng.standard_normal(f.size)
    if proxy.lsb_hz > 0:
        f = np.round(np.round(f / proxy.lsb_hz) * proxy.lsb_hz, 6)
    temps = {**rec.temperatures, proxy.topic: TemperatureColumns(stamps, f, rec.frame_id)}
    meta = dict(rec.meta)
    meta['gyro_proxy'] = {'topic': proxy.topic, 'unit': 'Hz', 'f0_hz': proxy.f0_hz,
                          'kf_hz_per_degC': proxy.kf_hz_per_degc, 'rate_hz': proxy.rate_hz,
                          'lsb_hz': proxy.lsb_hz, 'noise_hz': proxy.noise_hz,
                          'follows': f'the temperature driving the gyro (input {col})'}
    meta['temperature_variance'] = {**meta.get('temperature_variance', {}),
                                    proxy.topic: proxy.noise_hz ** 2 + proxy.lsb_hz ** 2 / 12}
    return dataclasses.replace(rec, temperatures=temps, meta=meta)


def proxy_truth(rec, proxy=ResonanceProxy()):
    """Return the true calibration of ``rec`` with the gyro driven by the proxy (Hz).

    The inputs are the recording's temperature inputs plus the proxy; the gyro bias
    polynomial sum_j c_j (T - T0)^j becomes sum_j c_j / kf^j (X - X0)^j with
    X0 = f0 + kf T0. The proxy follows the gyro's own (lagged) temperature, so its lag is 0.
    """
    t = rec.truth
    k = len(t.inputs)
    g = t.gyro
    kf = proxy.kf_hz_per_degc
    if isinstance(g, WholeUnitGyroModel):       # devices with scale/misalignment/g-sensitivity
        power = np.arange(g.offset.shape[0])[:, None]
        gyro = WholeUnitGyroModel(proxy.frequency(g.t0), g.offset / kf ** power,
                                  g.scale / kf ** (power[1:g.scale.shape[0] + 1]), g.m0, g.m1,
                                  g.m2, g.m3, g.coupling, input_unit='Hz')
    else:
        power = np.arange(g.coeffs.shape[0])[:, None]
        gyro = OffsetPolynomialModel(proxy.frequency(g.t0), g.coeffs / kf ** power,
                                     sensor='gyro', include_constant=g.include_constant,
                                     input_unit='Hz')
    f = rec.temperatures[proxy.topic].temperature
    inputs = list(t.inputs) + [TemperatureInput('gyro_resonance', proxy.topic, 'Hz')]
    filt = t.temperature_filter
    if filt is not None:
        filt = ThermalFilter(np.append(filt.tau_s, 0.0), filt.kind)
    return dataclasses.replace(
        t, gyro=gyro, inputs=inputs, gyro_input=[k, k, k],
        valid_range=np.vstack([t.valid_range, [f.min(), f.max()]]),
        temperature_filter=filt,
        notes=list(t.notes) + [f'gyro driven by its resonance frequency {proxy.topic} (Hz): '
                               f'f = {proxy.f0_hz:g} Hz + ({kf:g} Hz/degC) T'])


def write_proxy_scenario(output, name, seed=0, proxy=ResonanceProxy(), **kwargs):
    """Write scenario ``name`` with the proxy topic (``sim.write_scenario`` plus a truth).

    Returns write_scenario's dict with ``truth_proxy``: ``<output>.truth_proxy.yaml``.
    """
    made = []

    def add(rec):
        made.append(with_resonance_proxy(rec, proxy))
        return made[-1]

    info = write_scenario(output, name, seed, transform=add, **kwargs)
    info['truth_proxy'] = f'{info["bag"]}.truth_proxy.yaml'
    proxy_truth(made[0], proxy).save(info['truth_proxy'])
    return info
