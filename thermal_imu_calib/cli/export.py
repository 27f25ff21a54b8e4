"""``thermal-imu-calib export``: write a calibration for Kalibr, imu_tk, PX4, ArduPilot or imucal.

Registered in ``cli`` by ``add_parser``; errors are ``ExportRefused``/``CalibrationError``
(one line, exit 2). What a format cannot hold is refitted or refused, and the loss is
printed on stderr (and never hidden in a file we would refuse).
"""

import os
import sys

import yaml

from ..calibration import Calibration
from ..formats import EXTENSIONS, export_calibration, FORMATS
from ..formats.common import loss_text
from ..io.output import Outputs, write_atomic


def add_parser(sub):
    """Add the export subparser to ``sub`` and return it."""
    p = sub.add_parser('export', help='write a calibration in another tool\'s format')
    p.add_argument('calibration', metavar='CALIB.yaml')
    p.add_argument('--format', required=True, choices=FORMATS,
                   help='kalibr: imu.yaml noise model; imu_tk: <stem>_acc.calib and '
                        '<stem>_gyro.calib; px4: QGroundControl .params (TC_A*/TC_G*); '
                        'ardupilot: .parm (INS_TCAL1_*); json: imucal Ferraris JSON')
    p.add_argument('-o', '--output', help='file to write (imu_tk: the stem); default: the '
                   'calibration name with the format\'s extension')
    p.add_argument('--windows', metavar='FILE',
                   help='refit on the calibration\'s own windows (JSONL from `calibrate '
                        '--save-windows FILE`) instead of a grid over its valid range')
    p.add_argument('--temperature', type=float, metavar='DEGC',
                   help='imu_tk/json: temperature to evaluate the model at (default: its T0)')
    p.add_argument('--noise', metavar='NOISE.yaml',
                   help='kalibr: noise figures (`thermal-imu-calib noise LOG -o NOISE.yaml`) '
                        'when the calibration has none')
    p.add_argument('--rostopic', help='kalibr: IMU topic (default: from the noise figures)')
    p.add_argument('--update-rate', type=float, metavar='HZ',
                   help='kalibr: IMU rate (default: from the noise figures)')
    p.add_argument('--kalibr-model', default='calibrated',
                   choices=('calibrated', 'scale-misalignment'),
                   help='kalibr: calibrated (noise model only) or scale-misalignment (also '
                        'M, A, C_gyro_i in Kalibr\'s results layout, and our biases, at '
                        '--temperature or T0)')
    p.add_argument('--instance', type=int,
                   help='px4: TC_A<n>/TC_G<n> (default 0); ardupilot: INS_TCAL<n> (default 1)')
    p.add_argument('--accel-id', type=int, default=0, help='px4: TC_An_ID (CAL_ACC0_ID)')
    p.add_argument('--gyro-id', type=int, default=0, help='px4: TC_Gn_ID (CAL_GYRO0_ID)')
    p.add_argument('--force', action='store_true', help='overwrite existing files')
    return p


def _windows(path):
    from ..collection.segments import Windows
    with open(path) as f:
        w = Windows.from_jsonl(f.read())
    if not len(w):
        raise ValueError(f'--windows {path}: no windows in the file')
    return w


def cmd_export(args):
    """Run the export subcommand."""
    with open(args.calibration) as f:
        text = f.read()
    cal = Calibration.from_yaml(text, args.calibration)
    raw = yaml.safe_load(text)
    noise_text = None
    if args.noise:
        with open(args.noise) as f:
            noise_text = f.read()
    windows = _windows(args.windows) if args.windows else None
    if windows is not None and windows.n_inputs != len(cal.inputs):
        raise ValueError(f'--windows {args.windows} has {windows.n_inputs} temperature inputs, '
                         f'the calibration {len(cal.inputs)}')
    out = export_calibration(cal, args.format, raw, windows, args.temperature, noise_text,
                             args.rostopic, args.update_rate, args.kalibr_model, args.instance,
                             args.accel_id, args.gyro_id)
    stem = args.output or os.path.splitext(args.calibration)[0] + EXTENSIONS[args.format]
    outputs = Outputs([args.calibration, args.windows, args.noise], args.force)
    paths = {suffix: outputs.file(stem + suffix, '-o', f'{args.format} file',
                                  lambda _: False)   # an existing file needs --force
             for suffix in out.files}
    for suffix, body in out.files.items():
        write_atomic(paths[suffix], body)
    for note in out.notes:
        print(f'note: {note}', file=sys.stderr)
    for which, loss in out.loss.items():
        print(loss_text(which, loss), file=sys.stderr)
    print('wrote ' + ', '.join(paths.values()))
    return 0
