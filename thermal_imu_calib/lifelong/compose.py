"""A calibration composed of one sensor's model from each of two calibrations.

The swap gate judges the gyroscope and the accelerometer separately (``gate.decide``'s
verdicts). When a new estimate is better for one sensor only, taking all of it also
replaces the other sensor's model, which the held-out holds did not prove better: on
simulated robot months such swaps left the accelerometer's next day unchanged on average
and held most of its worse next days (docs/lifelong.md, "One sensor at a time").
``compose`` builds the calibration that takes the proven sensor's model from the new
estimate and keeps the other from the active one.

Two calibrations compose only when they read the same thermal inputs the same way: the
same inputs (topic and unit), the same temperature filter (none, or the same lags), the
same axis-to-input mapping per sensor and the same gravity. Each model keeps its own
policy beyond its range when one ``out_of_range`` can say both (``composed_policy``: a
clamped accelerometer with a linearly continued gyro is 'linear_gyro'), and its own
valid range (``Calibration.sensor_range``); ``valid_range`` spans both. No ROS import.
"""

from dataclasses import replace

import numpy as np

from ..calibration import Calibration, spanning_range
from . import gate

SENSORS = ('accel', 'gyro')


def _inputs(cal):
    return [(i.topic, i.unit) for i in cal.inputs]


def _filter(cal):
    f = cal.temperature_filter
    return None if f is None else (f.kind, tuple(np.round(np.asarray(f.tau_s, float), 9)))


def why_not(a, b, missing=False):
    """Return '' when ``a`` and ``b`` compose, else what differs (for the decision log).

    ``missing``: a calibration without one sensor's model (that sensor left raw) composes
    too; the composition then leaves the sensor raw where its source has no model.
    """
    if a is None or b is None:
        return 'no active calibration'
    if not missing and (a.accel is None or a.gyro is None or b.accel is None
                        or b.gyro is None):
        return 'one of them lacks a sensor model'
    if _inputs(a) != _inputs(b):
        return 'their thermal inputs differ'
    if _filter(a) != _filter(b):
        return 'their temperature filters (lags) differ'
    if list(a.accel_input) != list(b.accel_input) or list(a.gyro_input) != list(b.gyro_input):
        return 'their axis-to-input mappings differ'
    if composed_policy(a, b) is None or composed_policy(b, a) is None \
            or not np.isclose(a.gravity, b.gravity, rtol=0, atol=1e-9):
        return 'their gravity or out-of-range policy differ'
    return ''


#: (accel policy, gyro policy) -> the one ``Calibration.out_of_range`` that says both
POLICIES = {('clamp', 'clamp'): 'clamp', ('clamp', 'linear'): 'linear_gyro',
            ('linear', 'linear'): 'linear', ('extrapolate', 'extrapolate'): 'extrapolate'}


def composed_policy(accel_from, gyro_from):
    """Return the ``out_of_range`` of ``accel_from``'s accel with ``gyro_from``'s gyro.

    Each sensor keeps its source's policy beyond its range (``range_policy``); None when no
    single policy says both (e.g. a linear accelerometer with a clamped gyro).
    """
    return POLICIES.get((accel_from.range_policy('accel'), gyro_from.range_policy('gyro')))


def depends_on_temperature(model):
    """Return whether a sensor model's correction changes with its thermal input.

    False for a model of degree 0 in temperature (``temperature_degree``) without terms of
    the thermal history (``terms``): its own range says where it was fitted, not where it
    holds.
    """
    return model.temperature_degree() > 0 or bool(getattr(model, 'terms', ()))


def bounds_range(cal, which, sensors='every'):
    """Return whether ``which``'s own range bounds ``cal``'s common range.

    ``sensors`` (``LifelongConfig.range_sensors``): 'every' model with one does; 'thermal',
    only a model that depends on temperature (``depends_on_temperature``).
    """
    model = getattr(cal, which)
    return model is not None and (sensors == 'every' or depends_on_temperature(model))


def common_range(cal, sensors='every'):
    """Return the (k, 2) range inside every sensor's own range (None: no inputs).

    A composed calibration's ``valid_range`` spans both models; outside this one, one of
    them clamps (or extrapolates). The lifelong loop uses it for "inside the valid range":
    the range extension that makes a re-estimate due, the change alarm, diagnostics.
    ``sensors``: whose own ranges bound it (``bounds_range``; none: the valid range).
    """
    if cal is None or cal.valid_range is None:
        return None
    own = [np.asarray(cal.own_range(w), float) for w in SENSORS if bounds_range(cal, w, sensors)]
    if not own:
        return np.asarray(cal.valid_range, float)
    return np.stack([np.max([r[:, 0] for r in own], 0), np.min([r[:, 1] for r in own], 0)], 1)


def compose(accel_from, gyro_from, note='', missing=False):
    """Return the calibration with ``accel_from``'s accel model and ``gyro_from``'s gyro.

    Raises ValueError naming the difference when they do not compose (``why_not``;
    ``missing``: a source without the model leaves that sensor raw). Noise figures and a
    gyro ageing term follow their sensor; ``fit`` is the gyro source's, with ``composed``
    saying where each model came from.
    """
    why = why_not(accel_from, gyro_from, missing)
    if why:
        raise ValueError(f'the calibrations do not compose: {why}')
    ranges = {w: c.own_range(w) for w, c in (('accel', accel_from), ('gyro', gyro_from))
              if getattr(c, w) is not None}
    if not ranges:
        raise ValueError('the calibrations do not compose: neither sensor has a model')
    valid, sensor_range = None, {}
    if accel_from.inputs:          # the span of the models' own ranges (one model: its own)
        valid, sensor_range = spanning_range(ranges)
    noise = {k: v for k, v in (accel_from.noise_model or {}).items() if not k.startswith('gyro')}
    noise.update({k: v for k, v in (gyro_from.noise_model or {}).items()
                  if k.startswith('gyro')})
    filt = gyro_from.temperature_filter
    if filt is not None:
        spread = {w: (c.temperature_filter.restart_spread or {}).get(w)
                  for w, c in (('accel', accel_from), ('gyro', gyro_from))}
        spread = {w: v for w, v in spread.items() if v is not None}
        filt = replace(filt, restart_spread=spread or None)
    fit = dict(gyro_from.fit)
    fit['composed'] = {'accel_from': accel_from.id, 'gyro_from': gyro_from.id}
    notes = [n for n in gyro_from.notes]
    notes.append(f'composed: accelerometer model of calibration {accel_from.id}, gyroscope '
                 f'model of {gyro_from.id}' + (f' ({note})' if note else ''))
    return Calibration(
        accel=accel_from.accel, gyro=gyro_from.gyro, inputs=list(accel_from.inputs),
        valid_range=valid, out_of_range=composed_policy(accel_from, gyro_from),
        accel_input=list(accel_from.accel_input), gyro_input=list(gyro_from.gyro_input),
        frame_id=accel_from.frame_id or gyro_from.frame_id, gravity=accel_from.gravity,
        gravity_source=accel_from.gravity_source,
        accel_noise_std=accel_from.accel_noise_std, gyro_noise_std=gyro_from.gyro_noise_std,
        fit=fit, notes=notes, temperature_filter=filt,
        noise_model=noise, sensor_range=sensor_range,
        gyro_ageing=dict(gyro_from.gyro_ageing))


def with_sensor(active, new, which, raw_kept, note):
    """Return (calibration, None) with ``which`` sensor's model from ``new``, or (None, why).

    The other sensor's model is ``active``'s; with no active calibration it is left out
    (the raw output), which composes only with ``raw_kept`` (``why_not(missing=True)``).
    ``note`` says why in the composed calibration's notes.
    """
    other = 'gyro' if which == 'accel' else 'accel'
    base = active if active is not None else replace(new, **{other: None})
    why = why_not(base, new, missing=raw_kept)
    if why:
        return None, why
    pick = {w: new if w == which else base for w in SENSORS}
    return compose(pick['accel'], pick['gyro'], note=note, missing=raw_kept), None


def one_sensor(active, new, fig, s_act, holdout, pose, latitude, sigmas,
               accel_score='magnitude', raw_kept=False):
    """Return ((calibration, score, figures) or None, record) of a one-sensor swap.

    When the gate calls ``new`` better than ``active`` for one sensor only (``fig``'s
    verdicts), the composed calibration (that sensor's model from ``new``, the other from
    ``active``) is scored on the same held-out holds (``holdout``, accelerometer on
    ``pose``) and returned when it passes the gate against ``s_act``, the active's score
    on them (``gate.decide`` at ``sigmas``; ``accel_score`` as ``gate.score``). None:
    both or neither better, no active calibration, the two do not compose, or the
    composition fails the gate. ``raw_kept``: with no active calibration the raw output is
    the active one, so the other sensor stays raw (a calibration without its model), and
    such calibrations compose later (``why_not(missing=True)``). ``record`` (a dict, empty
    when nothing was tried) says what was tried, with both decisions' figures.
    """
    better = [w for w in SENSORS if fig[w]['verdict'] == 'better']
    if (active is None and not raw_kept) or len(better) != 1:
        return None, {}
    which = better[0]
    kept = 'kept' if active is not None else 'left raw'
    cal, why = with_sensor(active, new, which, raw_kept,
                           f'the {which} of the new estimate {new.id}, proven better on '
                           f'held-out holds; the other sensor {kept}')
    if why:
        return None, {'sensor': which, 'used': False,
                      'text': f'{which} only: not composed ({why})'}
    score = gate.score(cal, holdout, cal.gravity, pose, latitude, accel_score)
    ok, fig_c = gate.decide(s_act, score, sigmas)
    mine = "the active's other one" if active is not None else 'the other sensor raw'
    record = {'sensor': which, 'used': bool(ok), 'estimate_id': new.id, 'whole_figures': fig,
              'text': (f'{which} only: the new estimate {new.id} is better for the {which} '
                       f'alone; its {which} model with {mine} '
                       f'{"passes" if ok else "fails"} the gate ({gate.describe(fig_c)})')}
    return ((cal, score, fig_c) if ok else None), record


def one_sensor_swap(active, new, fig, s_act, holdout, pose, latitude, config, state,
                    decision):
    """Return ``one_sensor``'s swap (None: none) with the loop's settings.

    ``decision`` (dict) records it. Not after a change alarm (unless
    ``one_sensor_after_alarm``): the alarm says the sensor changed, and in one mounting
    pose the gate cannot see a change of the accelerometer's level (it compares the holds'
    spread about their median), so the whole new calibration is judged.
    """
    c = config
    if not c.per_sensor or (state.get('alarm_pending') and not c.one_sensor_after_alarm):
        return None
    found, record = one_sensor(active, new, fig, s_act, holdout, pose, latitude,
                               c.swap_sigmas, c.accel_score, c.raw_kept)
    if record:
        decision['one_sensor'] = record
    return found
