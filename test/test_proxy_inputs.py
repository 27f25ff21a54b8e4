"""Thermal proxy inputs: units in the file, refusals, mapping, I/O types, CLI end to end.

A proxy is a header-stamped scalar the thermal error follows that is not a temperature,
e.g. a MEMS gyro's drive-mode resonance frequency in Hz (seed 002). The end-to-end test
simulates a cold start whose gyro input is published as such a frequency, calibrates it
through the CLI with ``--input-unit`` and checks that the gyro bias it leaves on another
cold start of the same device is as small as with the die temperature.
"""

import copy
import json

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from thermal_imu_calib import sim
from thermal_imu_calib.calibration import Calibration, CalibrationError, TemperatureInput
from thermal_imu_calib.cli import main
from thermal_imu_calib.estimation.calibrate import (CalibrateOptions, calibrate_windows,
                                                    default_input_map, input_margins)
from thermal_imu_calib.input_units import normalize_unit, parse_unit_map
from thermal_imu_calib.io.bag import open_log
from thermal_imu_calib.io.bag_writer import write_columns
from thermal_imu_calib.io.columns import TemperatureColumns
from thermal_imu_calib.models.field import FieldPolynomialModel
from thermal_imu_calib.models.polynomial import OffsetPolynomialModel
from thermal_imu_calib.app.collect import collect_windows
from thermal_imu_calib.sim.proxy import proxy_truth, ResonanceProxy, with_resonance_proxy

PROXY = '/imu/gyro_resonance'


def proxy_cal():
    """Return a calibration: accel on a degC input, gyro on a Hz resonance frequency."""
    th = np.zeros((3, 6))
    th[:, 3], th[:, 4] = 0.05, 2e-3
    gyro = OffsetPolynomialModel([24955.0] * 3, [[1e-3] * 3, [-2e-4] * 3, [1e-6] * 3],
                                 'gyro', input_unit='Hz')
    return Calibration(
        accel=FieldPolynomialModel([30.0] * 3, th), gyro=gyro,
        inputs=[TemperatureInput('die', '/imu/temperature'),
                TemperatureInput('gyro_resonance', PROXY, 'Hz')],
        valid_range=np.array([[20.0, 40.0], [24940.0, 24970.0]]),
        accel_input=[0, 0, 0], gyro_input=[1, 1, 1], frame_id='imu_link')


def test_unit_spellings_and_refusals():
    assert normalize_unit('°C') == normalize_unit('celsius') == 'degC'
    assert normalize_unit('Hz') == 'Hz' and normalize_unit('kHz') == 'kHz'
    for bad, name in (('K', 'Kelvin'), ('kelvin', 'Kelvin'), ('degF', 'Fahrenheit'),
                      ('°F', 'Fahrenheit')):
        with pytest.raises(ValueError, match=f'{name}.*convert the readings.*declare degC'):
            normalize_unit(bad)
    with pytest.raises(ValueError, match='not a unit string'):
        normalize_unit('hertz per kelvin')
    assert parse_unit_map([f'{PROXY}=Hz'], ['/imu/temperature', PROXY]) == ['degC', 'Hz']
    assert parse_unit_map(['imu/gyro_resonance=Hz'], [PROXY]) == ['Hz']
    with pytest.raises(ValueError, match='not a thermal input.*--temperature-topic'):
        parse_unit_map(['/nope=Hz'], [PROXY])
    with pytest.raises(ValueError, match='TOPIC=UNIT'):
        parse_unit_map(['Hz'], [PROXY])


def test_degc_files_are_written_as_before():
    cal = proxy_cal()
    d = Calibration(accel=cal.accel, gyro=OffsetPolynomialModel([30.0] * 3, [[1e-3] * 3],
                                                                'gyro'),
                    inputs=cal.inputs[:1], valid_range=cal.valid_range[:1]).to_dict()
    assert d['temperature']['valid_range']['unit'] == 'degC'
    assert 'thermal_inputs' not in d['units']
    for sec in ('accel', 'gyro'):
        assert 'input_unit' not in d[sec]['meta']
        assert d[sec]['parameters']['T0'] == {'value': [30.0] * 3, 'unit': 'degC',
                                              'description': 'reference temperature per axis'}
    assert d['accel']['parameters']['b1']['unit'] == 'm/s^2/degC'
    # a file without any unit (older writer) still loads as degC
    for i in d['temperature']['inputs']:
        i.pop('unit')
    d['temperature']['valid_range'].pop('unit')
    back = Calibration.from_dict(d)
    assert back.input_units == ['degC'] and back.gyro.input_unit == 'degC'


def test_proxy_file_round_trip_records_units():
    cal = proxy_cal()
    d = cal.to_dict()
    assert [i['unit'] for i in d['temperature']['inputs']] == ['degC', 'Hz']
    assert d['temperature']['valid_range']['unit'] == ['degC', 'Hz']
    p = d['gyro']['parameters']
    assert p['T0']['unit'] == 'Hz' and p['c1']['unit'] == 'rad/s/Hz'
    assert p['c2']['unit'] == 'rad/s/Hz^2' and d['gyro']['meta']['input_unit'] == 'Hz'
    assert d['accel']['parameters']['T0']['unit'] == 'degC'
    back = Calibration.from_yaml(cal.to_yaml())
    assert back.id == cal.id and back.gyro.input_unit == 'Hz'
    rng = np.random.default_rng(0)
    temps = np.column_stack([rng.uniform(15, 45, 40), rng.uniform(24930, 24980, 40)])
    a, g = rng.normal(0, 9.8, (40, 3)), rng.normal(0, 0.1, (40, 3))
    r1, r2 = cal.apply(a, g, temps), back.apply(a, g, temps)
    np.testing.assert_array_equal(r1.gyro, r2.gyro)
    # the gyro follows the Hz column (clamped to its valid range) and nothing else
    x = np.clip(temps[:, 1], 24940.0, 24970.0) - 24955.0
    np.testing.assert_allclose(r1.gyro, g - (1e-3 - 2e-4 * x + 1e-6 * x * x)[:, None],
                               rtol=0, atol=1e-15)
    assert list(r1.out_of_range) == list((temps[:, 0] < 20) | (temps[:, 0] > 40)
                                         | (temps[:, 1] < 24940) | (temps[:, 1] > 24970))


def _set(path, value):
    def edit(d):
        node = d
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value
    return edit


@pytest.mark.parametrize('edit, message', [
    (_set(('temperature', 'inputs', 1, 'unit'), 'K'), 'Kelvin.*convert the readings.*degC'),
    (_set(('temperature', 'inputs', 0, 'unit'), 'degF'), 'Fahrenheit.*convert.*degC'),
    (_set(('temperature', 'valid_range', 'min'), [300.0, 24940.0]),
     'degC is outside.*Kelvin or Fahrenheit'),
    (_set(('temperature', 'valid_range', 'max'), [40.0, float('inf')]), 'not finite'),
    (_set(('temperature', 'valid_range', 'min'), [20.0, 24980.0]), 'min is above max'),
    (_set(('temperature', 'valid_range', 'unit'), 'degC'),
     "input 'gyro_resonance' is in degC but the input is in Hz"),
    (_set(('temperature', 'valid_range', 'unit'), ['degC']), 'has 1 entries for 2 inputs'),
    (_set(('gyro', 'temperature_input'), [0, 0, 0]),
     'gyro parameters are in Hz .* maps it to inputs in degC'),
    (_set(('accel', 'temperature_input'), [1, 1, 1]),
     'accel parameters are in degC .* maps it to inputs in Hz'),
    (_set(('gyro', 'temperature_input'), [0, 1, 1]), 'inputs of different units'),
    (_set(('temperature', 'inputs', 1, 'unit'), 'per second'), 'not a unit string'),
])
def test_bad_unit_files_are_refused_with_reason(edit, message):
    d = copy.deepcopy(proxy_cal().to_dict())
    edit(d)
    with pytest.raises(CalibrationError, match=message):
        Calibration.from_dict(d, 'x.yaml')


def test_reference_checks_follow_the_input_unit():
    d = proxy_cal().to_dict()
    assert d['gyro']['parameters']['T0']['value'][0] == 24955.0      # fine in Hz
    d['accel']['parameters']['T0']['value'] = [24955.0] * 3          # not as degC
    with pytest.raises(CalibrationError, match='T0 = .* degC is implausible'):
        Calibration.from_dict(d)
    with pytest.raises(CalibrationError, match='mapped to inputs in degC'):
        Calibration(gyro=OffsetPolynomialModel([1.0] * 3, [[0.0] * 3], 'gyro',
                                               input_unit='Hz'),
                    inputs=[TemperatureInput('t')], valid_range=np.array([[0.0, 1.0]]))
    with pytest.raises(ValueError, match='Kelvin'):
        TemperatureInput('t', unit='K')


def test_default_mapping_and_margins_by_unit():
    assert default_input_map(['degC']) == ([0, 0, 0], [0, 0, 0])
    assert default_input_map(['degC'] * 3) == ([0, 1, 2], [0, 0, 0])
    assert default_input_map(['Hz', 'degC']) == ([1, 1, 1], [0, 0, 0])
    assert default_input_map(['degC', 'degC', 'degC', 'Hz']) == ([0, 1, 2], [3, 3, 3])
    assert default_input_map(['Hz', 'Hz']) == ([0, 0, 0], [0, 0, 0])

    class Win:
        def __init__(self, temp):
            self.temp = temp
            self.n_inputs = temp.shape[1]

        def __len__(self):
            return self.temp.shape[0]

    t = np.linspace(20, 40, 9)
    win = Win(np.column_stack([t, 25000 - 1.5 * t]))
    inputs = [TemperatureInput('t'), TemperatureInput('f', PROXY, 'Hz')]
    o = CalibrateOptions(inputs=inputs, range_margin=1.0)
    np.testing.assert_allclose(input_margins(win, o), [1.0, 1.5])       # 1 degC in Hz
    o.unit_margins = {'Hz': 4.0}
    np.testing.assert_allclose(input_margins(win, o), [1.0, 4.0])
    o = CalibrateOptions(inputs=inputs[1:])
    np.testing.assert_allclose(input_margins(Win(win.temp[:, 1:]), o), [0.05 * 30])  # of span


def test_simulated_proxy_follows_the_gyro_temperature_and_truth_maps_to_it():
    rec = sim.simulate('demo', 2, repetitions=1)
    p = ResonanceProxy()
    prox = with_resonance_proxy(rec, p)
    f = prox.temperatures[PROXY]
    assert len(f) == pytest.approx(rec.duration * p.rate_hz, abs=2)
    temp = rec.temperature_at(f.stamp_ns, 'drive')[:, 0]
    err = f.temperature - p.frequency(temp)
    assert np.max(np.abs(err)) < 6 * p.noise_hz + p.lsb_hz
    assert np.allclose(np.round(f.temperature / p.lsb_hz), f.temperature / p.lsb_hz)
    assert set(prox.temperatures) == {'/imu/temperature', PROXY}
    truth = proxy_truth(prox, p)
    assert truth.input_units == ['degC', 'Hz'] and truth.gyro_input == [1, 1, 1]
    # the same physics: compensating with T or with f(T) gives the same gyro
    t = np.linspace(20.0, 40.0, 50)
    rec.truth.out_of_range = truth.out_of_range = 'extrapolate'   # no clamping at the edges
    raw = np.random.default_rng(1).normal(0, 0.01, (50, 3))
    a = rec.truth.apply(np.tile([0, 0, 9.8], (50, 1)), raw, t[:, None])
    b = truth.apply(np.tile([0, 0, 9.8], (50, 1)), raw, np.column_stack([t, p.frequency(t)]))
    np.testing.assert_allclose(a.gyro, b.gyro, rtol=0, atol=1e-12)


def test_other_stamped_scalar_types_carry_a_thermal_input(tmp_path):
    rec = sim.simulate('demo', 4, repetitions=1)
    tc = rec.temperatures['/imu/temperature']
    path = tmp_path / 'p.mcap'
    write_columns(path, '/imu/data_raw', rec.imu_chunks(),
                  {'/imu/temperature': tc, '/press': TemperatureColumns(
                      tc.stamp_ns, 1000.0 + tc.temperature, 'imu_link')},
                  msgtypes={'/press': 'sensor_msgs/msg/FluidPressure'},
                  temperature_variance={'/press': 0.25})
    with AnyReader([path]) as r:
        con = [c for c in r.connections if c.topic == '/press']
        assert con[0].msgtype == 'sensor_msgs/msg/FluidPressure'
        msg = r.deserialize(next(r.messages(connections=con))[2], con[0].msgtype)
    assert msg.fluid_pressure == 1000.0 + tc.temperature[0] and msg.variance == 0.25
    col = collect_windows(path, '/imu/data_raw', ['/imu/temperature', '/press'])
    np.testing.assert_allclose(col.windows.temp[:, 1], 1000.0 + col.windows.temp[:, 0],
                               atol=1e-9)
    with open_log(path) as r:
        assert '1022.' in r.info().format() or '1021.' in r.info().format()


@pytest.fixture(scope='module')
def proxy_bags(tmp_path_factory):
    d = tmp_path_factory.mktemp('proxy')
    cal = main(['simulate', str(d / 'cal.mcap'), '--scenario', 'demo', '--seed', '1',
                '--gyro-proxy'])
    val = main(['simulate', str(d / 'val.mcap'), '--scenario', 'demo-validation', '--seed',
                '1', '--gyro-proxy'])
    assert cal == val == 0
    return d


#: a fit may leave this many times the residual of the true parameters on the same log
TRUTH_FACTOR = 2.0


def gyro_bias_residual(bag, scenario, seed, topic='/imu/data_compensated'):
    """Return the RMS over holds of |mean gyro - true rate| (rad/s), holds trimmed by 2 s."""
    rec = sim.simulate(scenario, seed)
    chunks = list(rec.truth_chunks())
    ts = np.concatenate([c.stamp_ns for c in chunks])
    rate = np.concatenate([c.angular_rate for c in chunks])
    with open_log(bag) as r:
        got = [c.imu for c in r.stream(topic)]
    st = np.concatenate([c.stamp_ns for c in got])
    i = np.searchsorted(ts, st)
    assert np.array_equal(ts[i], st)
    err = np.concatenate([c.gyro for c in got]) - rate[i]
    means = [err[(st > h.stamp_start_ns + 2e9) & (st < h.stamp_end_ns - 2e9)].mean(0)
             for h in rec.schedule]
    return float(np.sqrt(np.mean(np.sum(np.square(means), axis=1))))


def test_cli_calibrates_a_gyro_on_its_resonance_frequency(proxy_bags, capsys):
    d = proxy_bags
    # the simulated MEMS gyro has g-sensitivity: the whole-unit model (seed 002) removes it
    common = [str(d / 'cal.mcap'), '--latitude', '45', '--model', 'whole_unit']
    assert main(['calibrate', *common, '--temperature-topic', '/imu/temperature',
                 '-o', str(d / 'degc.yaml')]) == 0
    assert main(['calibrate', *common, '--temperature-topic', '/imu/temperature',
                 '--temperature-topic', PROXY, '--input-unit', f'{PROXY}=Hz',
                 '-o', str(d / 'hz.yaml')]) == 0
    out = capsys.readouterr().out
    assert 'degC, 2494' in out and ' Hz, gravity residual' in out
    cal = Calibration.load(d / 'hz.yaml')
    assert cal.input_units == ['degC', 'Hz'] and cal.temperature_topics[1] == PROXY
    assert cal.gyro_input == [1, 1, 1] and cal.accel_input == [0, 0, 0]
    assert cal.gyro.input_unit == 'Hz' and cal.accel.input_unit == 'degC'
    assert cal.gyro.params()['cw1'].unit == 'rad/s/Hz'
    assert 24900 < cal.gyro.t0[0] < 25000
    # valid range: the collected range widened by 1 degC, i.e. ~1.5 Hz on the proxy
    f = cal.fit['temperature_span'][1]
    assert cal.valid_range[1, 0] == pytest.approx(f[0] - 1.5, abs=0.3)
    assert cal.fit['valid_range_margin']['unit'] == ['degC', 'Hz']
    assert main(['report', str(d / 'hz.yaml')]) == 0
    assert 'Hz]' in capsys.readouterr().out
    res = {}
    for name in ('degc', 'hz'):
        out_bag = d / f'val_{name}.mcap'
        assert main(['compensate', str(d / 'val.mcap'), '--calibration',
                     str(d / f'{name}.yaml'), '-o', str(out_bag)]) == 0
        res[name] = gyro_bias_residual(out_bag, 'demo-validation', 1)
    raw = gyro_bias_residual(d / 'val.mcap', 'demo-validation', 1, '/imu/data_raw')
    # what the simulator's true parameters achieve on the same log (the attainable floor)
    assert main(['compensate', str(d / 'val.mcap'), '--calibration',
                 str(d / 'val.mcap.truth.yaml'), '-o', str(d / 'val_truth.mcap')]) == 0
    truth = gyro_bias_residual(d / 'val_truth.mcap', 'demo-validation', 1)
    with capsys.disabled():
        print(f'gyro bias residual [rad/s]: raw {raw:.3g}, truth {truth:.3g}, degC input '
              f'{res["degc"]:.3g}, Hz proxy {res["hz"]:.3g}')
    assert res['hz'] < TRUTH_FACTOR * truth and res['degc'] < TRUTH_FACTOR * truth
    assert res['hz'] < 1.25 * res['degc']
    # evaluate reads the units from the files; drift per degC is taken on the degC input
    capsys.readouterr()
    assert main(['evaluate', str(d / 'val.mcap'), '--calibration', str(d / 'hz.yaml'),
                 '--calibration', str(d / 'degc.yaml'), '--calibration',
                 str(d / 'val.mcap.truth.yaml'), '--json']) == 0
    ev = json.loads(capsys.readouterr().out)
    assert ev['temperature_topics'] == ['/imu/temperature', PROXY]
    r = ev['results']
    rate = {k: v['gyro_rate_rms']['value'] for k, v in r.items()}
    assert rate['hz'] < 1.1 * rate['degc'], rate
    assert rate['hz'] < TRUTH_FACTOR * rate['val.mcap.truth'], rate   # truth on the same holds
    assert all(20 < h['temp_range'][0] < 40 for h in r['hz']['per_hold'])


def test_cli_refuses_kelvin_and_unknown_unit_topics(proxy_bags, capsys):
    d = proxy_bags
    base = ['calibrate', str(d / 'cal.mcap'), '--temperature-topic', '/imu/temperature',
            '-o', str(d / 'x.yaml')]
    assert main(base + ['--input-unit', '/imu/temperature=K']) == 2
    assert 'Kelvin' in capsys.readouterr().err
    assert main(base + ['--input-unit', f'{PROXY}=Hz']) == 2
    assert 'not a thermal input' in capsys.readouterr().err
    assert main(base + ['--gyro-input', PROXY]) == 2
    assert 'must name one or three' in capsys.readouterr().err


def test_lag_applies_to_the_temperature_not_to_the_proxy():
    """One pose, errors following the die temperature through a 240-s lag (``lag-warmup``).

    The resonance frequency follows the gyro's own (lagged) temperature: the lag search
    lags only the degC input, and the gyro on the proxy needs none.
    """
    from thermal_imu_calib.collection.metrics import WindowAccumulator
    from thermal_imu_calib.collection.feed import windows_from_columns

    def windows(rec):
        return windows_from_columns(rec.imu_chunks(), [rec.temperatures['/imu/temperature'],
                                                       rec.temperatures[PROXY]])
    cal_rec = with_resonance_proxy(sim.simulate('lag-warmup', 0))
    val_rec = with_resonance_proxy(sim.simulate('lag-warmup', 0, tau_s=300.0, t_amb=23.0))
    wc, wv = windows(cal_rec), windows(val_rec)
    acc = WindowAccumulator(wv.t0, wv.t1)
    for tc in val_rec.truth_chunks():
        acc.add(tc.stamp_ns * 1e-9, {'w': tc.angular_rate})
    rate = acc.means('w')
    die = TemperatureInput('die', '/imu/temperature')
    drift = {}
    for label, w, inputs, cols in (
            ('degC', wc.select(np.ones(len(wc), bool)), [die], [0]),
            ('Hz', wc, [die, TemperatureInput('f', PROXY, 'Hz')], [0, 1])):
        if label == 'degC':
            w.temp, w.temp_rate = w.temp[:, :1], w.temp_rate[:, :1]
        cal = calibrate_windows(w, CalibrateOptions(model='auto', inputs=inputs)).calibration
        # the lag is the calibration's filter, or (one-way path, degC only) the models'
        # lagged input
        f = cal.temperature_filter
        tau = f.tau_s if f is not None else [float(cal.gyro.base.split(':')[1])]
        assert 150 < tau[0] < 350 and (label == 'degC' or tau[1] == 0.0), tau
        assert cal.gyro.input_unit == label
        g = cal.stream().apply(0.5 * (wv.t0 + wv.t1), wv.accel, wv.gyro, wv.temp[:, cols]).gyro
        d = g - rate
        drift[label] = float(np.sqrt(np.mean((d - d.mean(0)) ** 2)))
    d = wv.gyro - rate
    raw = float(np.sqrt(np.mean((d - d.mean(0)) ** 2)))
    # what the simulator's true calibration (die temperature through its 240-s lag) leaves on
    # the same validation windows: the fitted models are 2.4-3.5x that on seeds 0-3 (seed 0:
    # 2.5x degC, 2.6x Hz), both fitted out of sample on another run
    truth = val_rec.truth
    g = truth.stream().apply(0.5 * (wv.t0 + wv.t1), wv.accel, wv.gyro,
                             wv.temp[:, :len(truth.temperature_topics)]).gyro
    d = g - rate
    true = float(np.sqrt(np.mean((d - d.mean(0)) ** 2)))
    msg = (f'gyro drift RMS [rad/s]: degC input {drift["degC"]:.3g}, Hz proxy '
           f'{drift["Hz"]:.3g}, true parameters {true:.3g}, raw {raw:.3g}')
    assert drift['Hz'] < 1.25 * drift['degC'], msg
    assert drift['Hz'] < 4 * true and drift['degC'] < 4 * true, msg
