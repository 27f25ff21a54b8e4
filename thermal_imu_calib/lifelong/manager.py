"""The lifelong loop: holds in, re-estimate when due, swap only when proven, history out.

``Lifelong`` owns a directory (its files are read and written by ``files``)::

    holds/        the bounded hold store (``store.HoldStore``)
    active.yaml   the calibration in use (the node publishes ``output``, see below)
    candidate.yaml the newest estimate that did not pass the swap gate
    state.json    counters (holds at the last estimate, the active's held-out figures)
    decisions.jsonl every decision with its figures (the newest ``files.MAX_DECISIONS`` kept)
    follower.jsonl  the gyro follower's offsets (``follower``; the newest kept likewise)
    archive/<UTC time>/ what a reset moved aside (``holds/``, ``candidate.yaml``)

and, when ``registry_dir`` is given, adds every calibration it activates to a registry in
the fleet format (``fleet.registry``: ``history``, drift alarms and the compensator's
registry mode then work for one robot; ``valid_from`` is the time it was activated).

When to re-estimate (``due``, ``trigger.due``): the first time enough holds are in; when
the collected temperatures extend the active calibration's valid range and what the last
estimate fitted; when ``new_holds`` holds came in, or ``misfit_holds`` holds the active
calibration misses, since the last estimate; after a change alarm. The estimate is
``app.calibrate.calibrate_collected`` (the command line's calibrate) on the store's windows
without the newest ``holdout_holds`` holds, which the swap gate (``gate.decide``) scores
both calibrations on. When it is better for one sensor only, that sensor's model alone
replaces the active one's (``compose``, ``per_sensor``). The fit with the gyro ageing
removed, a sensor's kept history after a one-sensor alarm and the refit of a swap on every
hold are ``variants``; the settings are ``config.LifelongConfig``.

Change alarm (a knock, ``alarm``): every new hold inside the active valid range is scored
with the active calibration; when, for one sensor, the last ``alarm_holds`` of them all
miss its reference by the alarm's limit, the store is cut at the first of them (with
``alarm_cut`` 'shift': the holds before the change are moved by the step the newer ones
show, ``knock_step``), an alarm is logged and a re-estimate follows. A swap measures the
alarm's reference anew (``_activate``).

Reset (``reset``, the node's ``~/reset``): the collection starts afresh without losing
data: the hold store and the candidate move into ``archive/<UTC time>/`` (at most
``MAX_ARCHIVES`` archives; one more is refused, saying what to do), the active
calibration, the counters, the decisions and the registry stay. No ROS import.

Gyro follower (``gyro_follow``, on): ``output``, the published calibration, takes off the
gyro the active model's recent miss (``follower``); every decision judges the model. A
swap may wait for later holds to judge it (``prequential_holds``, off: ``prequential``).

``Lifelong`` holds the state the pieces share (the counters, the active calibration, the
store) and applies what they return; the pieces are ``trigger``, ``gate``, ``compose``,
``variants``, ``ageing``, ``alarm``, ``incumbent``, ``prequential``, ``store``, ``files``,
``status`` and ``archive``.
"""

import os
import time
from dataclasses import replace

import numpy as np

from ..app.calibrate import calibrate_collected
from ..estimation.calibrate import CalibrationRefused
from ..io.output import write_atomic
from ..collection.collected import Collected
from . import alarm, compose, continuation, files, follower, g_sensitivity, gate, incumbent, \
    knock_step, pooled, prequential, status, trigger, variants
from ..collection.segments import Windows
from .archive import ArchiveFull, archive_collection, MAX_ARCHIVES  # noqa: F401 (API)
from .config import (ALARM_CUTS, ALARM_REFERENCES, ALARM_WINDOWS,  # noqa: F401 (API)
                     LifelongConfig)
from .pose import main_pose, main_pose_mask, pose_of
from .store import HoldStore

#: the follower's offsets (``follower.follow`` records), JSON lines, the newest kept
FOLLOWER_LOG = 'follower.jsonl'


class Lifelong:
    """Lifelong calibration state of one IMU (see the module docstring)."""

    def __init__(self, directory, settings, k, topics, frame_id='', sensor='',
                 registry_dir='', config=None, log=None):
        self.dir = os.path.expanduser(directory)
        self.settings = settings
        self.k = int(k)
        self.topics = list(topics)
        self.frame_id = frame_id
        self.sensor = sensor or frame_id or 'imu'
        self.registry_dir = os.path.expanduser(registry_dir) if registry_dir else ''
        self.config = config or LifelongConfig()
        for name in ('placement_folds', 'placement_floor'):   # a robot's stops: placements
            if getattr(self.config, name):
                self.settings = replace(self.settings, **{name: True})
        if self.config.placement_levels:
            self.settings = replace(self.settings, placement_levels=True,
                                    placement_levels_sensors=self.config.placement_levels_sensors)
        #: deg or None: the swap gate takes the known vertical earth rate off the gyro
        self.latitude = getattr(settings, 'latitude', None)
        self.log = log or (lambda level, text: None)
        os.makedirs(self.dir, exist_ok=True)
        self.store = HoldStore(os.path.join(self.dir, 'holds'), self.k, self.config.store)
        for note in self.store.notes:
            self.log('warn', note)
        self.active = files.load_calibration(self._path('active.yaml'), self.log)
        self.candidate = files.load_calibration(self._path('candidate.yaml'), self.log)
        self.state = {'holds_at_estimate': 0, 'active_since': None, 'active_gyro_rms': None,
                      'active_accel_rms': None, 'active_noise': None, 'alarms': 0,
                      'alarm_pending': False, 'swaps': 0, 'kept': 0, 'estimates': 0,
                      'last_decision': ''}
        files.load_state(self._path('state.json'), self.state, self.log)
        self.pending = files.load_calibration(self._path(prequential.PENDING), self.log) \
            if self.state.get('pending') else None      # a swap held back (``prequential``)
        self.state['pending'] = self.state.get('pending') if self.pending else None
        self.track = []     # [alarm.Tracked]: the newest holds the change alarm watches
        #: (windows, main-pose mask) of the estimate running, for the gyro g-sensitivity
        self._pool, self._specs = None, {}      # _specs: ``incumbent.note``'s
        #: the calibration to publish: the active one, with the follower's offset when on
        self.output = self.active
        self._follow(record=False)

    # ------------------------------------------------------------------ files
    def _path(self, name):
        return os.path.join(self.dir, name)

    def _save_state(self):
        files.write_state(self._path('state.json'), self.state)

    def _record(self, decision):
        files.append_decision(self._path('decisions.jsonl'), decision)

    def decisions(self, last=None):
        """Return the logged decision records (dicts), oldest first."""
        return files.read_decisions(self._path('decisions.jsonl'), last)

    # ------------------------------------------------------------------ output
    def _follow(self, record=True):
        """Set ``output`` (``follower.output``); log a changed offset when ``record``."""
        before = self.output
        self.output, row = follower.output(self.active, self.store.recent, self.latitude,
                                           self.config)
        if record and row is not None and self.output is not before:
            files.append_decision(self._path(FOLLOWER_LOG), row | {'output': self.output.id})

    # ------------------------------------------------------------------ reset
    def reset(self, when=None):
        """Start the collection afresh; the old one is archived, nothing is deleted.

        The store (and the candidate) move into ``archive/<UTC time>/``
        (``archive_collection``); the active calibration stays active, the state's counters
        and the decisions stay, the next re-estimate waits for new holds. Returns the
        decision dict (action 'reset', logged); raises ``ArchiveFull`` or ``OSError`` with
        nothing changed.
        """
        before = self.store.summary()
        rec = self.store.recent
        newest = float(rec.t1.max()) if len(rec) else None
        dest = archive_collection(self.dir, when)
        self.store = HoldStore(os.path.join(self.dir, 'holds'), self.k, self.config.store)
        self.candidate = None
        self._drop_pending()
        self.track = []
        self.state.update(holds_at_estimate=0, alarm_pending=False, missed=[], fit_span=None,
                          resets=self.state.get('resets', 0) + 1)
        n = before['holds_total']
        moved = (f'moved the {n} hold{"s" if n != 1 else ""} collected so far '
                 f'({before["raw_holds"]} raw, {before["compacted_bins"]} compacted bins) to '
                 f'{dest}/ (kept there, not deleted)' if dest else 'nothing collected yet')
        kept = (f'the active calibration {self.active.id} stays active until a new one '
                'passes the swap gate' if self.active is not None
                else 'no active calibration yet')
        self._follow()
        decision = {'time': newest, 'action': 'reset',
                    'wall_time': time.time() if when is None else float(when),
                    'reason': 'requested', 'archive': dest, 'archived': before,
                    'text': f'collection restarted: {moved}; {kept}'}
        self.state['last_decision'] = decision['text']
        self._record(decision)
        self._save_state()
        self.log('info', f'lifelong reset: {decision["text"]}')
        return decision

    # ------------------------------------------------------------------ holds
    def add(self, windows):
        """Add the (gated) windows of closed holds; check them against the active model."""
        if not len(windows):
            return []
        ids = self.store.add(windows)
        if self.active is not None:
            self._check_change(self.store.holds(ids))
        self._follow()
        return ids

    def _check_change(self, windows):
        """Score new holds with the active calibration; on a change alarm, cut the store."""
        cal, s, c = self.active, self.state, self.config
        e = gate.hold_errors(cal, windows, cal.gravity, self.latitude)
        if c.gyro_continuation != 'off' and not s.get('alarm_pending'):
            continuation.add(s, continuation.rows(cal, windows, cal.gravity, self.latitude))
        missed = alarm.new_misses(e, s, c)
        if missed:
            s['missed'] = (s.get('missed') or []) + missed
        ranges = alarm.alarm_ranges(cal, self.k, c.alarm_window, c.range_sensors)
        self.track = alarm.tracked(self.track, e, ranges, s.get('active_accel_median') or 0.0)
        if s.get('active_gyro_rms') is None or s.get('alarm_pending'):
            return
        out, first = alarm.exceeded(self.track, s, c)
        if out:
            t_cut, t_now = alarm.first_hold_start(self.store.recent, min(first)), self.track[-1].t
            moved = knock_step.step(cal, self.store.recent, t_cut, cal.gravity,
                                    self.latitude, c.pose_deg, ranges) \
                if c.alarm_cut == 'shift' else None
            decision, keep = alarm.alarm_decision(out, t_cut, t_now, c, moved)
            s['alarms'] += 1
            s['alarm_pending'] = True
            continuation.cut(s, t_cut)
            pooled.clear(s)
            s['alarm_shifted'] = moved is not None
            self.track = []
            if moved is None:
                self.store.cut(t_cut, keep=keep)
            else:
                self.store.shift(moved['t'], moved['accel'], moved['gyro'], moved['drop'])
            s['last_decision'] = decision['reason']
            self._drop_pending()
            self._record(decision)
            self._save_state()
            self.log('error', 'lifelong ALARM: ' + decision['reason'])

    # ------------------------------------------------------------------ when
    def due(self):
        """Return why a re-estimate is due now ('' when it is not; ``trigger.due``).

        While a swap is held back, only its judgement can be (``prequential``).
        """
        c = self.config
        if self.pending is not None:
            return prequential.REASON if prequential.ready(self.store, self.state, c) else ''
        return trigger.due(self.store, self.state, c, self.active, self.k, self.track)

    # ------------------------------------------------------------------ estimate
    def estimate(self, reason='requested'):
        """Re-estimate and pass the swap gate; return the decision dict (also logged)."""
        if reason == prequential.REASON and self.pending is not None:
            return self._confirm()
        c = self.config
        held = self.store.newest_holds(c.holdout_holds)
        now = float(self.store.recent.t1.max()) if len(self.store.recent) else 0.0
        everything, times = self.store.fit_windows(now, exclude=held)
        in_pose = main_pose_mask(everything, self.config.pose_deg)
        self._pool = (everything, in_pose) if c.gyro_g_sensitivity else None
        fit, times = everything.select(in_pose), times[in_pose]
        holdout = self.store.holds(held)
        holdout_pose = main_pose(holdout, self.config.pose_deg, reference=pose_of(fit))
        self.state['holds_at_estimate'] = self.store.total_holds
        self.state['estimates'] += 1
        self.state['missed'] = []
        self._note_fit_span(fit)
        decision = {'time': now, 'reason': reason, 'fit_windows': len(fit),
                    'fit_holds': int(len(fit.hold_ids)) if len(fit) else 0,
                    'heldout_holds': int(len(held))}
        try:
            if len(fit) == 0 or len(fit.hold_ids) < c.min_holds // 2 or len(held) < 2:
                raise CalibrationRefused('too few holds', 'wait for more stops')
            result = self._calibrate(fit)
        except variants.REFUSALS as e:
            decision.update(action='refused', text=f'no new calibration: {e}')
            return self._finish(decision)
        except Exception as e:  # noqa: B902 - an estimator bug must not end the loop
            decision.update(action='failed', text=f'estimation failed ({e.__class__.__name__}: '
                                                  f'{e}); the active calibration stays')
            return self._finish(decision)
        new = result.calibration
        g = new.gravity
        s_new = gate.score(new, holdout, g, holdout_pose, self.latitude, c.accel_score)
        aged = variants.with_ageing(self._calibrate, fit, times, now, holdout, holdout_pose,
                                    s_new, decision, c, self.latitude)
        if aged is not None:
            result, s_new = aged
            new = result.calibration
        kept = variants.with_kept(self._calibrate, self.store, c.pose_deg, new, now, held,
                                  decision)
        if kept is not None:
            new = kept
            s_new = gate.score(new, holdout, g, holdout_pose, self.latitude, c.accel_score)
        s_act = gate.score(self.active, holdout, g, holdout_pose, self.latitude,
                           c.accel_score)
        swap, fig = gate.decide(s_act, s_new, c.swap_sigmas)
        part = compose.one_sensor_swap(self.active, new, fig, s_act, holdout, holdout_pose,
                                       self.latitude, c, self.state, decision)
        only = ''
        if part is not None:
            new, s_new, fig = part
            swap, only = True, decision['one_sensor']['sensor']
        if swap:
            swap = not self._unexplained(s_new, decision)
        if c.gyro_pooled_gate and not swap:     # the evidence of estimates that keep the gyro
            part, record = pooled.judge(self.state, self.active, new, fig, s_act, s_new,
                                        holdout, holdout_pose, self.latitude, c)
            if record:
                decision['pooled'] = record
            if part is not None:
                if self._unexplained(part[1], decision):
                    record['used'] = False      # the log says it was not swapped
                else:
                    (new, s_new, fig), swap, only = part, True, 'gyro'
        decision['figures'] = fig
        for key in ('g_sensitivity', 'continuation'):
            if key in result.report:
                decision[key] = result.report[key]
        decision['model'] = new.accel.kind if new.accel is not None else 'gyro only'
        decision['summary'] = result.summary
        versus = 'the active calibration' if self.active is not None else 'the raw output'
        text = gate.describe(fig) + decision.get('unexplained', '')
        if decision.get('pooled'):
            text += '; ' + decision['pooled']['text']
        if 'kept_history' in decision:
            text += '; ' + decision['kept_history']['text']
        text += ''.join('; ' + decision[k] for k in ('g_sensitivity', 'continuation')
                        if k in decision)
        if swap:
            if c.refit_on_swap:
                new, fitted = variants.refit(self._calibrate, self.store, c, self.active, new,
                                             now, decision, only)
                if decision['refit']['used']:
                    self._note_fit_span(fitted)
                text += '; ' + decision['refit']['text']
            # a refit active: the next estimate waits for min_holds + holdout_holds holds
            # newer than its fit (``due``); any other swap ends that wait
            fit_until = now if decision.get('refit', {}).get('used') else None
            if prequential.holds_back(c, self.state, self.active):
                return self._hold_back(new, now, only, fit_until, decision, text)
            self.state['active_fit_until'] = fit_until
            text += self._activate(new, now, s_new, holdout_pose, held, only or None)
            only = f' ({only} model only)' if only else ''
            decision.update(action='swap', id=new.id,
                            text=f'new calibration {new.id} replaces {versus}{only}: {text}')
        else:
            self._make_candidate(new, kept=True)
            decision.update(action='keep', id=new.id,
                            text=f'kept {versus}; new calibration {new.id} is a candidate: '
                                 f'{text}')
        self.state['alarm_pending'] = False
        return self._finish(decision)

    def _hold_back(self, new, now, only, fit_until, decision, text):
        """Keep a swap the gate passed until later holds judge it (``prequential``)."""
        self.pending = new
        self._save_cal(new, prequential.PENDING)
        self.state['pending'] = prequential.record(new, now, only or None, fit_until)
        only = f' ({only} model only)' if only else ''
        decision.update(action='pending', id=new.id, text=(
            f'new calibration {new.id} passes the swap gate{only}: {text}; held back until '
            f'{self.config.prequential_holds} later holds judge it'))
        return self._finish(decision)

    def _confirm(self):
        """Judge the held-back swap on the holds after its estimate; take it or keep it."""
        p, cal = self.state['pending'], self.pending
        take, fig, s_new, pose, ids = prequential.judge(self.active, cal, self.store,
                                                        self.state, self.config, self.latitude)
        now = float(self.store.recent.t1.max())
        self.pending, self.state['pending'] = None, None
        files.remove(self._path(prequential.PENDING))
        why = prequential.describe(fig, take, len(ids))
        decision = {'time': now, 'reason': prequential.REASON, 'heldout_holds': int(len(ids)),
                    'figures': fig, 'held_back': p}
        if take:
            self.state['active_fit_until'] = p.get('fit_until')
            note = self._activate(cal, now, s_new, pose, ids, p.get('only'))
            only = f' ({p["only"]} model only)' if p.get('only') else ''
            decision.update(action='swap', id=cal.id, text=(
                f'new calibration {cal.id} replaces the active calibration{only}: {why}{note}'))
        else:
            self._make_candidate(cal, kept=True)
            decision.update(action='keep', id=cal.id, text=(
                f'kept the active calibration; new calibration {cal.id} is a candidate: {why}'))
        return self._finish(decision)

    def _drop_pending(self):
        """Make a held-back calibration the candidate (a change alarm, a reset)."""
        if self.pending is not None:
            self._make_candidate(self.pending, kept=False)
        self.pending, self.state['pending'] = None, None
        files.remove(self._path(prequential.PENDING))

    def _make_candidate(self, cal, kept):
        """Make ``cal`` the candidate (``candidate.yaml``); ``kept``: count a kept swap."""
        self.candidate = cal
        self._save_cal(cal, 'candidate.yaml')
        self.state['kept'] += int(kept)

    def _unexplained(self, s_new, decision):
        """Return True (no swap) when the new calibration misses the newest holds too.

        ``gate.unexplained`` (``LifelongConfig.swap_must_explain``); the decision records it.
        """
        note = gate.unexplained(s_new, self.state, self.config, self.active is not None)
        if note:
            decision['unexplained'] = note
        return bool(note)

    def _note_fit_span(self, fit):
        """Keep the temperature span (degC) an estimate fitted (``due``'s range trigger)."""
        self.state['fit_span'] = trigger.fit_span(fit, self.k)

    def _calibrate(self, windows):
        """Return ``calibrate_collected``'s result on these windows (the CLI's calibrate).

        With ``LifelongConfig.gyro_g_sensitivity`` the gyro also takes the g-sensitivity
        the holds off the mounting pose support, held out (``g_sensitivity``); with
        ``gyro_continuation`` 'history' its policy beyond the range is the one the holds
        outside the earlier active calibrations' ranges support (``continuation``).
        """
        collected = Collected(windows, self.frame_id, 0, 0.0, list(self.topics), [])
        result = calibrate_collected(self.settings, [collected], incumbent_specs=(
            incumbent.offered(self.state, self.config)))
        if self._pool is not None:
            everything, in_pose = self._pool
            coupling = g_sensitivity.learn(result.calibration, everything, in_pose,
                                           result.calibration.gravity, self.latitude)
            cal, note = g_sensitivity.attach(result.calibration, coupling)
            result = replace(result, calibration=cal, summary=result.summary + '; ' + note,
                             report={**result.report, 'g_sensitivity': note})
        if self.config.gyro_continuation != 'off':
            cal, note = continuation.choose(result.calibration,
                                            self.state.get('continuation') or [],
                                            self.config.swap_sigmas,
                                            self.config.gyro_continuation == 'span')
            if note:
                result = replace(result, calibration=cal,
                                 summary=result.summary + '; ' + note,
                                 report={**result.report, 'continuation': note})
        incumbent.note(self._specs, result)     # the models as they are kept
        return result

    def _finish(self, decision):
        self.state['last_decision'] = decision['text']
        self._record(decision)
        self._save_state()
        self.log('info' if decision['action'] in ('swap', 'keep') else 'warn',
                 f'lifelong {decision["action"]} ({decision["reason"]}): {decision["text"]}')
        return decision

    def _save_cal(self, cal, name):
        write_atomic(self._path(name), cal.to_yaml())

    def _activate(self, cal, now, s_new, holdout, held, only=None):
        """Make ``cal`` the active calibration; ``only``: the one sensor it replaced.

        The change alarm's reference (the error the calibration leaves, per sensor) is
        measured anew, except for a sensor a one-sensor swap left unchanged: its model is
        the same, so is its error reference (re-measured on holds that span a change the
        model does not explain, it would grow and hide that change from the alarm). The
        accelerometer's level (the median of |a| - g) is always measured anew.
        """
        before = {k: self.state.get(k) for k in ('active_gyro_rms', 'active_accel_rms')}
        self.active = cal
        incumbent.activate(self.state, self._specs, cal, only)
        self._follow()
        self.candidate = None
        files.remove(self._path('candidate.yaml'))
        self._save_cal(cal, 'active.yaml')
        # the alarm's reference: the error the calibration leaves on the raw holds it was
        # fitted on (all their temperatures) and on the held-out ones, whichever is larger
        rec = self.store.recent
        raw = main_pose(rec.select(~np.isin(rec.hold, held)), self.config.pose_deg) \
            if len(rec) else rec
        both = gate.hold_errors(cal, Windows.concat([raw, holdout]), cal.gravity,
                                self.latitude)
        med = float(np.median(both['accel']))
        is_held = np.isin(both['ids'], held)
        errs = {'gyro': both['gyro'], 'accel': both['accel'] - med}
        use, note = alarm.reference_holds(both, errs, before, self.config,
                                          self.state.get('alarm_pending'), only)
        ref = {}
        held_rms = {'gyro': s_new['gyro_rms'], 'accel': s_new['accel_magnitude_rms']}
        for which, err in errs.items():
            m = use[which]
            ref[which] = (max(held_rms[which], gate.rms(err)) if m.all() else
                          max(gate.rms(err[m & is_held]) if (m & is_held).any() else 0.0,
                              gate.rms(err[m])))
        self.state.update(active_since=now, active_gyro_rms=ref['gyro'],
                          active_accel_rms=ref['accel'], active_accel_median=med,
                          active_noise=s_new['noise_gyro'], swaps=self.state['swaps'] + 1)
        kept = {'accel': ('active_gyro_rms',), 'gyro': ('active_accel_rms',)}.get(only, ())
        self.state.update({k: before[k] for k in kept if before[k] is not None})
        self.track = []
        if only != 'accel':          # the active gyro model changed: its evidence starts anew
            pooled.clear(self.state)
        if self.registry_dir:
            from ..fleet import registry
            t_ns = int(now * 1e9)
            try:
                registry.add(self.registry_dir, [(self.sensor, cal, t_ns, t_ns, [])])
            except (OSError, ValueError) as e:
                self.log('error', f'registry {self.registry_dir} not updated: {e}')
        return note

    # ------------------------------------------------------------------ status
    def status(self, temperature=None, now=None):
        """Return the figures /diagnostics shows (``status.figures``)."""
        return status.figures(self, temperature, now)
