"""The console script starts with one BLAS thread unless the user chose (cli.entry)."""

import os
import shutil
import subprocess
import sys

CHILD = '''
import os
from thermal_imu_calib.cli import entry as cli_entry
try:
    cli_entry.main(['--version'])
except SystemExit:
    pass
from threadpoolctl import threadpool_info
print(os.environ['OPENBLAS_NUM_THREADS'],
      max(i['num_threads'] for i in threadpool_info() if i['internal_api'] == 'openblas'))
'''


def _run(env_value):
    env = dict(os.environ)
    env.pop('OPENBLAS_NUM_THREADS', None)
    if env_value is not None:
        env['OPENBLAS_NUM_THREADS'] = env_value
    out = subprocess.run([sys.executable, '-c', CHILD], env=env, capture_output=True,
                         text=True, check=True)
    return out.stdout.split()[-2:]


def test_one_blas_thread_before_numpy_loads_and_a_user_choice_is_kept():
    assert _run(None) == ['1', '1']
    assert _run('2')[0] == '2'                # the user's value is not overridden


def test_the_installed_console_script_goes_through_the_entry_module():
    script = shutil.which('thermal-imu-calib',
                          path=os.path.dirname(sys.executable) + os.pathsep + os.environ['PATH'])
    assert script is not None, 'thermal-imu-calib is not installed next to this python'
    with open(script) as f:
        assert 'thermal_imu_calib.cli.entry' in f.read()
