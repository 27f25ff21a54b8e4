"""The gyro swap judged on the held-out evidence of successive estimates: a sequential test.

The swap gate (``gate.decide``) judges each new estimate on the newest ``holdout_holds``
holds alone. On simulated robot months the gyro bias ages between swaps; estimate after
estimate the candidate's gyro is better on its held-out holds, each time by less than the
gate's noise floor (the RMS standard error of the hold means), so the active gyro grows old
(docs/lifelong.md). With ``LifelongConfig.gyro_pooled_gate`` the evidence is pooled:

* **Rows.** While one active gyro model stays, each estimate adds, for every held-out hold
  not pooled yet (by its end time), the row (t s, active gyro error, candidate gyro error,
  standard error; rad/s, ``gate.hold_errors``). Successive estimates hold out overlapping
  holds; each hold counts once, with the first candidate that did not see it.
* **Emptied** when the active gyro model changes (a swap that replaces it) and at a change
  alarm (the sensor changed: the rows before it say nothing of the sensor after it).
* **Verdict.** The gate's own rule (``gate.compare``) on the pool, with the noise floor of
  the pool's size: the gate's floor (the RMS standard error of the hold means) times
  ``sqrt(holdout_holds / pooled holds)``, the same floor at the gate's own number of holds,
  shrinking as one over the square root of the independent holds, as a standard error does.
  The paired term (``sigmas`` times the standard error of the paired difference) is the
  gate's.

The manager asks for a verdict only when the gate kept the active gyro and the estimate's
own candidate is better on its held-out holds too; 'better' then swaps the candidate's
gyro model alone (``compose.with_sensor``). The rows say the active gyro has aged against
fresh fits it did not see; the candidate is the freshest of those fits. No ROS import.
"""

import numpy as np

from . import compose, gate

#: most rows kept, newest last (a memory bound; a pool this long has long been judged)
MAX_ROWS = 2000


def rows(s_act, s_new):
    """Return [[t s, active error, candidate error, standard error]] (rad/s) per held-out hold.

    ``s_act``, ``s_new``: ``gate.score`` of the active and the candidate calibration on the
    same held-out holds.
    """
    a, n = s_act['errors'], s_new['errors']
    return [[float(t), float(x), float(y), float(s)] for t, x, y, s in
            zip(a['t'], np.abs(a['gyro']), np.abs(n['gyro']), a['se_gyro'])]


def add(state, new_rows):
    """Append the rows of holds not pooled yet to ``state['gyro_pool']``; return how many."""
    pool = state.get('gyro_pool') or []
    seen = {round(r[0], 3) for r in pool}
    fresh = [r for r in new_rows if round(r[0], 3) not in seen]
    state['gyro_pool'] = (pool + fresh)[-MAX_ROWS:]
    return len(fresh)


def clear(state):
    """Empty the pool (the active gyro model changed, or a change alarm)."""
    state.pop('gyro_pool', None)


def verdict(pool, holdout_holds, sigmas):
    """Return the pooled figures (``gate.compare``'s, with 'holds' and 'floor'; rad/s).

    The noise floor is the RMS standard error of the pooled holds times
    ``sqrt(holdout_holds / len(pool))`` (at most the gate's own floor).
    """
    r = np.asarray(pool, float).reshape(-1, 4)
    h = len(r)
    if h < 2:
        return {**gate.compare(r[:, 1], r[:, 2], 0.0, sigmas), 'holds': h, 'floor': 0.0,
                'verdict': 'same'}
    floor = gate.rms(r[:, 3]) * np.sqrt(min(1.0, holdout_holds / h))
    fig = gate.compare(r[:, 1], r[:, 2], floor, sigmas)
    fig.update(holds=h, floor=float(floor))
    return fig


def describe(fig):
    """Return the pooled figures as one phrase (mdeg/s)."""
    scale = np.degrees(1.0) * 1e3
    return (f'gyro pooled over {fig["holds"]} held-out holds since the active gyro was '
            f'swapped in: {fig["active_rms"] * scale:.3g} -> {fig["new_rms"] * scale:.3g} '
            f'mdeg/s (margin {fig["margin"] * scale:.2g}: {fig["verdict"]})')


def judge(state, active, new, fig, s_act, s_new, holdout, pose, latitude, config):
    """Pool this estimate's rows; return ((calibration, score, figures) or None, record).

    Called when the gate did not swap the gyro (``fig``: ``gate.decide``'s figures of the
    estimate). Nothing is judged without an active calibration, while a change alarm is
    pending, or when the candidate's own gyro is not better on its held-out holds. On a
    pooled 'better' the composed calibration (the candidate's gyro, the active's
    accelerometer; ``compose.with_sensor``) is returned when, on this estimate's held-out
    holds, its gyro is better and its accelerometer not 'worse' (``gate.decide`` at
    ``config.swap_sigmas``). ``record`` (empty: nothing pooled) says what was done.
    """
    if active is None or state.get('alarm_pending'):
        return None, {}
    added = add(state, rows(s_act, s_new))
    record = {'added': added, 'pooled_holds': len(state['gyro_pool']), 'used': False}
    if fig['gyro']['gain'] <= 0:
        record['text'] = (f'gyro pooled over {record["pooled_holds"]} held-out holds, not '
                          'judged: the candidate\'s gyro is not better on its own')
        return None, record
    pf = verdict(state['gyro_pool'], config.holdout_holds, config.swap_sigmas)
    record.update(figures=pf, text=describe(pf))
    if pf['verdict'] != 'better':
        return None, record
    cal, why = compose.with_sensor(active, new, 'gyro', config.raw_kept,
                                   f'the gyro of the new estimate {new.id}, better than the '
                                   'active one on the pooled held-out holds')
    if why:
        record['text'] += f'; gyro only: not composed ({why})'
        return None, record
    score = gate.score(cal, holdout, cal.gravity, pose, latitude, config.accel_score)
    _, fig_c = gate.decide(s_act, score, config.swap_sigmas)
    ok = fig_c['gyro']['gain'] > 0 and fig_c['accel']['verdict'] != 'worse'
    record.update(used=bool(ok), text=record['text'] + (
        f'; its gyro with the active accelerometer {"passes" if ok else "fails"} on this '
        f'estimate\'s holds ({gate.describe(fig_c)})'))
    return ((cal, score, fig_c) if ok else None), record
