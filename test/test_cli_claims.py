"""Claims of the CLI with no test before (issue 15 item 8): --prior, several INPUTs.

* ``calibrate --prior`` (a lab calibration: k0, b0, S at T0) refines Delta k0, Delta b0 and
  the thermal terms of the field model; checked against the simulator's true device over
  the valid range, in every direction, and against the same log without the prior (which
  cannot know the non-orthogonality S).
* ``calibrate A B``: the holds of both logs are merged (counted per log, independently).
"""

import numpy as np
import pytest

from thermal_imu_calib import sim
from thermal_imu_calib.calibration import Calibration
from thermal_imu_calib.cli import main

G = 9.80665


@pytest.fixture(scope='module')
def nav_log(tmp_path_factory):
    d = tmp_path_factory.mktemp('nav')
    # a shortened nav cold start: 2 x six faces, 60-70 s holds over a 10-min warm-up
    paths = sim.write_scenario(d / 'nav.mcap', 'nav-coldstart', 1, repetitions=2,
                               hold_s=(60.0, 70.0), first_hold_s=(60.0, 70.0), tau_s=600.0)
    return d, paths


def _direction_errors(cal, truth, rng):
    """Return (errors (m, 3), predict_std (m, 3)) over random directions and the range."""
    lo, hi = cal.valid_range[:, 0].max(), cal.valid_range[:, 1].min()
    f = rng.normal(size=(200, 3))
    f = G * f / np.linalg.norm(f, axis=1, keepdims=True)
    temps = np.tile(rng.uniform(lo, hi, (200, 1)), (1, 3))
    err = cal.accel.correct(truth.accel.forward(f, temps), temps) - f
    return err, cal.accel.predict_std(temps)


def test_field_model_with_a_lab_prior_against_the_truth(nav_log):
    d, paths = nav_log
    # the local gravity of the simulation (45 deg, 0 m): a wrong g biases Delta k0
    common = [str(paths['bag']), '--model', 'field', '--latitude', '45']
    assert main(['calibrate', *common, '--prior', str(paths['prior']),
                 '-o', str(d / 'with.yaml')]) == 0
    assert main(['calibrate', *common, '-o', str(d / 'without.yaml')]) == 0
    truth = Calibration.load(paths['truth'])
    prior = Calibration.load(paths['prior'])
    with_p, without = Calibration.load(d / 'with.yaml'), Calibration.load(d / 'without.yaml')
    # the prior's k0, b0, S are carried; Delta k0, Delta b0 and the thermal terms refined
    np.testing.assert_array_equal(with_p.accel.k0, prior.accel.k0)
    np.testing.assert_array_equal(with_p.accel.s, prior.accel.s)
    z = (with_p.accel.thermal - truth.accel.thermal) / with_p.accel.thermal_std
    assert np.all(np.abs(z) < 5), z
    rng = np.random.default_rng(0)
    err, std = _direction_errors(with_p, truth, rng)
    err_wo, _ = _direction_errors(without, truth, np.random.default_rng(0))
    rms, rms_wo = np.sqrt(np.mean(err ** 2)), np.sqrt(np.mean(err_wo ** 2))
    std_rms = np.sqrt(np.mean(std ** 2))
    print(f'error vs truth in random directions: with prior {rms * 1e6 / G:.1f} ug, '
          f'without {rms_wo * 1e6 / G:.1f} ug, model std {std_rms * 1e6 / G:.1f} ug')
    # measured (seed 1): 40 ug with the prior, 51 ug without, std 96 ug (conservative: the
    # parameter correlations are ignored, docs/uncertainty.md)
    assert rms <= 1.5 * std_rms                         # within its stated uncertainty
    assert rms < rms_wo                                  # the lab S and k0, b0 help


def test_several_inputs_are_merged(tmp_path):
    bags = []
    for name in ('demo', 'demo-validation'):
        paths = sim.write_scenario(tmp_path / f'{name}.mcap', name, 1, repetitions=1)
        bags.append(str(paths['bag']))
    holds = []
    for i, bag in enumerate(bags):
        out = str(tmp_path / f'{i}.yaml')
        assert main(['calibrate', bag, '--model', 'field', '-o', out]) == 0
        holds.append(Calibration.load(tmp_path / f'{i}.yaml').fit['holds'])
    out = str(tmp_path / 'both.yaml')
    assert main(['calibrate', *bags, '--model', 'field', '-o', out]) == 0
    both = Calibration.load(tmp_path / 'both.yaml')
    assert both.fit['holds'] == sum(holds), (both.fit['holds'], holds)
    assert both.fit['inputs'] == ['demo.mcap', 'demo-validation.mcap']
    assert both.fit['windows'] > max(Calibration.load(tmp_path / f'{i}.yaml').fit['windows']
                                     for i in range(2))
