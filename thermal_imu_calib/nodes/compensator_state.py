"""The compensator's thermal-history state kept in a file across restarts (``state_file``).

A calibration whose models depend on the thermal history (a ``temperature.filter`` lag,
``hysteresis_offset`` terms) carries running lag states in its ``CalibrationStream``. A
restarted compensator would start them in equilibrium and widen its 1-sigma by what the
unknown history may hold (``restart_spread``); in a ramp faster than any the calibration
saw, the step can still exceed that (docs/thermal_models.md). With ``state_file`` the node
writes the stream state (``CalibrationStream.state``, JSON, atomically; ``{node}`` in the
path is the node's name, ``file_name``) every
``state_save_period`` seconds of wall time and on shutdown, and a new node of the same name
and calibration (same id) resumes from it at its first IMU sample when that sample is at
most ``state_max_gap`` seconds (header stamps) after the saved one: the gap is run through
like any gap in one stream (the reading interpolated), so there is no restart step and no
restart widening. Otherwise (another calibration, a longer gap, stamps that went back, an
unreadable file) the stream starts in equilibrium as before and the log says why. No
state is written for a calibration without history terms.
"""

import json
import os
import time

from ..io.output import OutputError, write_atomic

#: format tag of the state file
KIND = 'thermal_imu_calib/compensator_state'


def file_name(path, node):
    """Return ``path`` with ``{node}`` replaced by the node's name (``/ns/name`` -> ``ns.name``).

    So one configured path serves several compensators (one per IMU namespace).
    """
    return path.replace('{node}', node.strip('/').replace('/', '.') or 'node')


class StreamStateFile:
    """Save and resume one compensator's ``CalibrationStream`` state (see the module)."""

    def __init__(self, path, period_s, max_gap_s, logger, owner=''):
        self.owner = str(owner)
        self.path = os.path.expanduser(file_name(path, self.owner)) if path else ''
        self.period_s = float(period_s)
        self.max_gap_s = float(max_gap_s)
        self.log = logger
        self._saved = self._read() if self.path else None
        self._pending = None       # (ActiveModel, saved stream state) until its first sample
        self._next_save = 0.0
        self._save_failed = False
        self.resumed = False

    def _read(self):
        if not os.path.exists(self.path):
            return None
        try:
            with open(self.path, encoding='utf-8') as f:
                d = json.load(f)
            if not isinstance(d, dict) or d.get('kind') != KIND:
                raise ValueError('not a compensator state file')
            return d
        except (OSError, ValueError) as e:
            self.log.warning(f'state_file {self.path}: not used ({e}); the thermal history '
                             'starts in equilibrium (it is rewritten as the node runs)')
            return None

    def activated(self, model):
        """Note a newly active model; its first sample may resume the saved state."""
        self._pending = None
        if not self.path or model is None or model.stream.state() is None:
            return
        saved = self._saved
        if saved is None:
            return
        if saved.get('node', self.owner) != self.owner:
            self.log.warning(f'state_file {self.path}: written by {saved.get("node")}, not this '
                             f'node ({self.owner}): not resumed; give each compensator its own '
                             'state_file')
            return
        if saved.get('calibration_id') != model.id:
            self.log.info(f'state_file {self.path}: saved for calibration '
                          f'{saved.get("calibration_id")}, not the active {model.id}: not '
                          'resumed (the thermal history starts in equilibrium)')
            return
        self._pending = (model, saved.get('stream'))

    def before(self, model, t_first):
        """Resume the saved state into ``model``'s stream if ``t_first`` (s) is close enough."""
        if self._pending is None or self._pending[0] is not model:
            return
        _, state = self._pending
        self._pending = None
        self._saved = None
        last = (state or {}).get('t_last')
        gap = float('nan') if last is None else t_first - float(last)
        if not 0.0 <= gap <= self.max_gap_s:
            self.log.info(f'state_file {self.path}: the first sample is {gap:.1f} s after the '
                          f'saved state (resumed only within 0..{self.max_gap_s:g} s): the '
                          'thermal history starts in equilibrium')
            return
        try:
            model.stream.restore(state)
        except (ValueError, KeyError, TypeError) as e:
            self.log.warning(f'state_file {self.path}: not resumed ({e})')
            return
        self.resumed = True
        self.log.info(f'resumed the thermal history saved {gap:.1f} s (header stamps) before '
                      f'this sample from {self.path}: no restart step')

    def after(self, model, force=False):
        """Write ``model``'s stream state when the save period has passed (or ``force``)."""
        if not self.path or model is None:
            return
        now = time.monotonic()
        if not force and now < self._next_save:
            return
        self._next_save = now + self.period_s
        state = model.stream.state()
        if state is None or state.get('t_last') is None:
            return
        text = json.dumps({'kind': KIND, 'node': self.owner, 'calibration_id': model.id,
                           'saved_wall_time': time.time(), 'stream': state})
        try:
            write_atomic(self.path, text)
        except (OSError, OutputError) as e:
            if not self._save_failed:
                self.log.warning(f'state_file {self.path}: could not be written ({e}); '
                                 'compensating on without it')
            self._save_failed = True
