"""Calibrations to and from other tools: Kalibr, imu_tk, PX4, ArduPilot, imucal (one module each).

``export_calibration`` writes a Calibration in a format; ``read_calibration`` reads any of
those files back (faithfully: a PX4 file becomes the same cubic offsets); ``load_prior``
turns any of them, or a thermal_imu_calib file, into the prior ``calibrate --prior`` uses
(k0, b0, S at T0 of a seed 000 field model).
"""

import os

import numpy as np
import yaml

from ..calibration import (Calibration, CalibrationError, check_yaml_shape, decode_text,
                           FILE_FORMATS, MAX_FILE_BYTES)
from ..models.field import FieldPolynomialModel
from . import ardupilot, imu_tk, imucal, kalibr, px4
from .common import affine_map, Exported, ExportRefused, lq, samples  # noqa: F401

FORMATS = ('kalibr', 'imu_tk', 'px4', 'ardupilot', 'json')
#: default file name suffix per format (imu_tk: the triad suffixes are added to the stem)
EXTENSIONS = {'kalibr': '.yaml', 'imu_tk': '', 'px4': '.params', 'ardupilot': '.parm',
              'json': '.json'}


def export_calibration(cal, fmt, raw_dict=None, windows=None, temperature=None,
                       noise_text=None, rostopic=None, update_rate=None, kalibr_model=None,
                       instance=None, accel_id=0, gyro_id=0):
    """Return ``Exported`` for format ``fmt`` (see FORMATS); raises ExportRefused with why."""
    if fmt == 'kalibr':
        return kalibr.export(cal, raw_dict, noise_text, rostopic, update_rate,
                             kalibr_model or 'calibrated', temperature,
                             samples(cal, windows) if kalibr_model == 'scale-misalignment'
                             else None)
    if fmt == 'imu_tk':
        return imu_tk.export(cal, samples(cal, windows), temperature)
    if fmt == 'json':
        return imucal.export(cal, samples(cal, windows), temperature)
    header = 'written by thermal_imu_calib export'
    if fmt == 'px4':
        return px4.export(cal, samples(cal, windows), instance or 0, accel_id, gyro_id, header)
    if fmt == 'ardupilot':
        return ardupilot.export(cal, samples(cal, windows), instance or 1, header)
    raise ExportRefused(f'unknown format {fmt!r}; choose one of {", ".join(FORMATS)}')


def _read_text(path):
    with open(path, 'rb') as f:
        return decode_text(f.read(MAX_FILE_BYTES + 1), path)   # names the file if not UTF-8


def read_calibration(path):
    """Read a thermal_imu_calib, Kalibr, imu_tk, imucal, PX4 or ArduPilot file.

    The kind is told by name and content: ``*_acc.calib``/``*_gyro.calib`` (imu_tk; the
    sibling triad is read too), ``.json`` (imucal), ``.params`` (PX4, QGroundControl),
    ``.parm`` (ArduPilot), YAML with ``format: thermal_imu_calib/1`` (or ``/2``) or Kalibr's keys.
    Raises CalibrationError saying what the file is not.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise CalibrationError(f'{path!r} is a directory; pass the calibration file itself')
    if not os.path.isfile(path):
        raise CalibrationError(f'{path!r} does not exist' if not os.path.lexists(path) else
                               f'{path!r} is not a regular file; pass a calibration file')
    name = os.path.basename(path)
    try:
        if name.endswith(('_acc.calib', '_gyro.calib')):
            stem = path[:-len('_acc.calib')] if name.endswith('_acc.calib') \
                else path[:-len('_gyro.calib')]
            texts = {w: _read_text(stem + s) for w, s in imu_tk.SUFFIX.items()
                     if os.path.isfile(stem + s)}
            return imu_tk.read(texts, name)
        text = _read_text(path)
        if name.endswith('.json'):
            return imucal.read(text, name)
        if name.endswith('.params'):
            return px4.read(text, name)
        if name.endswith('.parm'):
            return ardupilot.read(text, name)
        if name.endswith('.calib'):
            return imu_tk.read({'accel': text}, name)
        check_yaml_shape(text, path)      # size, depth, alias limits before parsing
        try:
            d = yaml.safe_load(text)
        except yaml.YAMLError:
            d = None
        if isinstance(d, dict) and d.get('format') in FILE_FORMATS:
            return Calibration.from_dict(d, path)
        if isinstance(d, dict) and any(k in d for k in kalibr.KEYS):
            return kalibr.read(text, name)
        if isinstance(d, dict) and 'format' in d:
            return Calibration.from_dict(d, path)   # says which format it is not
    except RecursionError:
        raise CalibrationError(f'{path}: nested too deeply to be a calibration (JSON/YAML '
                               'structures inside structures thousands deep); is it the right '
                               'file?') from None
    except ValueError as e:
        if isinstance(e, CalibrationError):
            raise
        raise CalibrationError(str(e)) from None
    raise CalibrationError(f'{path}: not a calibration this package reads (thermal_imu_calib '
                           'YAML, Kalibr imu.yaml, imu_tk *_acc.calib, imucal .json, PX4 '
                           '.params, ArduPilot .parm)')


def as_prior(cal):
    """Return (prior Calibration, notes): the accel as k0, b0, S at T0 of a field model.

    A field model is kept as it is. Any other affine accel model at its T0 is written as
    corrected = S^-1 diag(1/k0) (raw - b0): M^-1 = L Q (LQ decomposition), k0 = diag(L),
    S = L / k0 row-wise (lower-triangular, the seed 000 frame: x = the x sensing axis); the
    rotation Q between the two frames is reported. Thermal terms are not a prior (the field
    fit estimates its own) and are dropped with a note.
    """
    notes = []
    model = cal.accel
    if model is None or isinstance(model, FieldPolynomialModel):
        return cal, notes
    t0 = np.asarray(model.t0, float)
    m, b, _, dropped = affine_map(model, t0, 'accel')
    lower, rot = lq(np.linalg.inv(m))
    k0 = np.diag(lower).copy()
    s = lower / k0[:, None]
    angle = np.degrees(np.arccos(np.clip((np.trace(rot) - 1) / 2, -1, 1)))
    if angle > 1e-9:
        notes.append(f'the prior\'s frame is rotated by {angle:.4g} deg into the seed 000 '
                     'frame (x = accelerometer x axis, y in the x-y sensing plane)')
    if dropped:
        notes.append(f'prior: {dropped}')
    notes.append(f'prior from {model.kind}: k0, b0 and S at T0 = {np.mean(t0):.2f} degC; its '
                 'thermal terms are not used')
    prior = Calibration(accel=FieldPolynomialModel(t0, np.zeros((3, 6)), k0, b, s),
                        gyro=cal.gyro, inputs=list(cal.inputs), valid_range=cal.valid_range,
                        accel_input=cal.accel_input, gyro_input=cal.gyro_input,
                        fit=dict(cal.fit), notes=list(cal.notes) + notes)
    return prior, notes


def load_prior(path):
    """Return the prior Calibration ``calibrate --prior PATH`` uses (any readable format)."""
    cal = read_calibration(path)
    prior, _ = as_prior(cal)
    return prior
