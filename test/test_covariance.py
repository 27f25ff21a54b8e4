"""The covariance of docs/uncertainty.md: the formula by hand, and its coverage on the truth.

``Calibration.apply`` returns ``accel_std = sqrt(model_std(T)^2 + noise^2)`` (the Imu
covariance diagonal). Here ``model_std`` is computed by hand from the file's coefficient
stds for the offset polynomial (the field model's is checked in ``test_core_models``), and
its coverage is measured against the simulator's true parameters: over the valid
temperature range, each axis along +-g, the model error divided by ``predict_std`` must
have a pooled RMS near 1 over independent devices (stds neither inflated nor optimistic).
"""

from _thermal_data import options, sim_windows
import numpy as np

from thermal_imu_calib import sim
from thermal_imu_calib.calibration import Calibration, TemperatureInput
from thermal_imu_calib.estimation.calibrate import calibrate_windows
from thermal_imu_calib.models.polynomial import OffsetPolynomialModel

G = 9.80665
SEEDS = (1, 2, 3, 4)


def test_offset_polynomial_std_by_hand():
    rng = np.random.default_rng(3)
    coeffs, std = rng.normal(0, 1e-3, (3, 3)), np.abs(rng.normal(0, 1e-4, (3, 3)))
    t0 = np.array([24.0, 25.0, 26.0])
    gyro = OffsetPolynomialModel(t0, coeffs, sensor='gyro', coeff_std=std)
    cal = Calibration(gyro=gyro, inputs=[TemperatureInput('t', '/imu/temperature')],
                      valid_range=np.array([[10.0, 40.0]]), gyro_noise_std=np.full(3, 2e-3))
    t = rng.uniform(0, 50, (40, 1))
    out = Calibration.from_yaml(cal.to_yaml()).apply(np.zeros((40, 3)), np.zeros((40, 3)), t)
    d = np.clip(t, 10.0, 40.0) - t0                       # clamped to the valid range
    model_var = std[0] ** 2 + (std[1] * d) ** 2 + (std[2] * d ** 2) ** 2
    np.testing.assert_allclose(out.gyro_std, np.sqrt(model_var + 2e-3 ** 2), rtol=1e-12)
    np.testing.assert_allclose(out.gyro, -(coeffs[0] + coeffs[1] * d + coeffs[2] * d ** 2),
                               rtol=1e-12, atol=1e-15)


def pooled_z(model):
    """Return the pooled RMS of (model error / predict_std) over SEEDS, axes, +-g, T grid."""
    z = []
    for seed in SEEDS:
        rec = sim.simulate('demo', seed)
        o = options(1)
        o.model = model
        cal = calibrate_windows(sim_windows(rec), o).calibration
        lo, hi = cal.valid_range[0]
        temps = np.tile(np.linspace(lo, hi, 7)[:, None], (1, 3))
        for i in range(3):
            for sign in (1.0, -1.0):
                f = np.zeros((7, 3))
                f[:, i] = sign * G
                # along the axis: the true non-orthogonality S (not estimated from a nominal
                # prior) changes (S f)_i by < 1e-6 g, far below the stds
                err = cal.accel.correct(rec.truth.accel.forward(f, temps), temps) - f
                z.append(err[:, i] / cal.accel.predict_std(temps)[:, i])
    return float(np.sqrt(np.mean(np.square(np.concatenate(z)))))


def test_field_model_std_covers_the_true_error():
    z_rms = pooled_z('field')
    print(f'field: pooled z-RMS {z_rms:.2f}')
    assert 0.6 <= z_rms <= 1.5, z_rms


def test_whole_unit_model_std_covers_the_true_error():
    z_rms = pooled_z('whole_unit')
    print(f'whole_unit: pooled z-RMS {z_rms:.2f}')
    assert 0.6 <= z_rms <= 1.5, z_rms
