"""The files of a lifelong directory: calibrations, counters and the decision log.

``active.yaml`` and ``candidate.yaml`` are read with ``load_calibration`` (an unreadable
one is moved aside to ``*.unreadable-<unix time s>``, never deleted), ``state.json`` (the
loop's counters) with ``load_state`` and ``write_state``, ``decisions.jsonl`` (one JSON
object a line, the newest ``MAX_DECISIONS`` kept) with ``append_decision`` and
``read_decisions``. Writes that replace a file are atomic (``io.output.write_atomic``).
No ROS import.
"""

import json
import os
import time

import numpy as np

from ..calibration import Calibration, CalibrationError
from ..io.output import free_name, write_atomic

MAX_DECISIONS = 2000


def load_calibration(path, log):
    """Return the calibration at ``path``, None when there is none or it is unreadable.

    An unreadable one is logged (``log(level, text)``) and moved aside.
    """
    if not os.path.exists(path):
        return None
    try:
        return Calibration.load(path)
    except (OSError, CalibrationError, ValueError) as e:
        log('error', f'{path} not loaded ({e}); moved aside')
        os.replace(path, free_name(path + f'.unreadable-{int(time.time())}'))
        return None


def load_state(path, state, log):
    """Update the counters ``state`` (dict) from the JSON file ``path``, when there is one.

    An unreadable file leaves ``state`` as it is and is logged (``log(level, text)``).
    """
    try:
        with open(path) as f:
            state.update(json.load(f))
    except FileNotFoundError:
        pass
    except (OSError, ValueError) as e:
        log('warn', f'{path} unreadable ({e}); counters reset')


def write_state(path, state):
    """Write the counters ``state`` (dict) to ``path`` as JSON."""
    write_atomic(path, json.dumps(state, indent=1))


def remove(path):
    """Remove the file ``path`` if it exists (a candidate or held-back calibration)."""
    if os.path.exists(path):
        os.unlink(path)


def append_decision(path, decision):
    """Append ``decision`` (dict) to the log at ``path``; keep its newest ``MAX_DECISIONS``."""
    line = json.dumps(decision, separators=(',', ':'), default=_plain) + '\n'
    with open(path, 'a') as f:
        f.write(line)
    if os.path.getsize(path) > 600 * MAX_DECISIONS:
        with open(path) as f:
            lines = f.readlines()[-MAX_DECISIONS:]
        write_atomic(path, ''.join(lines))


def read_decisions(path, last=None):
    """Return the decision records (dicts) logged at ``path``, oldest first (``last``: those)."""
    try:
        with open(path) as f:
            out = [json.loads(x) for x in f if x.strip()]
    except FileNotFoundError:
        return []
    return out[-last:] if last else out


def _plain(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)
