"""The thermal spec of the calibration in use, offered to the next estimate (``incumbent_spec``).

In one mounting pose the swap gate judges the accelerometer on |a| - g, which sees the
vertical axis only; a horizontal axis reads its offset plus g times the floor's tilt at
each stop, so the gate cannot tell whether a new estimate's horizontal thermal shape is
better (docs/lifelong.md). What changes that shape most is the choice of spec: the history
path picks the simplest candidate within ``time_folds.MARGIN`` of the best, and on a
robot's stops the candidates' held-out figures are close (the tilt dominates them), so the
pick moves between near ties from one estimate to the next (e.g. from a linear slope to
no thermal terms at all). With ``LifelongConfig.incumbent_spec`` the spec of the model in
use is scored with the other candidates and kept whenever it is in that pool
(``CalibrateOptions.incumbent_specs``): the spec changes only when held-out blocks say it
is worse than the best by more than the margin. The coefficients are refitted on every
hold as before.

Which spec a model was fitted with is known only from the estimate's report
(``history_select``: ``<sensor>_history``), so the loop notes it per model object when it
estimates (``note``) and keeps the active calibration's in its state when it activates
one (``activate``; one-sensor swaps keep the other sensor's).
"""

from ..estimation.hysteresis import spec_from_dict

#: ``LifelongConfig.incumbent_spec``: the sensors whose spec in use is offered
SENSORS = {'off': (), 'accel': ('accel',), 'both': ('accel', 'gyro')}


def from_state(item):
    """Return the ``Spec`` (or 'rvm') kept in the state; None for anything else."""
    if isinstance(item, str):
        return item if item == 'rvm' else None
    return spec_from_dict(item) if isinstance(item, dict) else None


def note(seen, result):
    """Remember the spec of each model of a ``calibrate_collected`` result (``seen``: dict).

    ``seen`` maps ``id(model)`` to (model, spec state); the model is held so its id is not
    reused while the loop runs.
    """
    for sensor in ('accel', 'gyro'):
        model = getattr(result.calibration, sensor)
        spec = (result.report.get(f'{sensor}_history') or {}).get('spec_state')
        if model is not None and spec is not None:
            seen[id(model)] = (model, spec)
    while len(seen) > 64:                   # the newest estimates' models are enough
        seen.pop(next(iter(seen)))


def activate(state, seen, cal, only=None):
    """Keep in ``state['active_specs']`` the specs of ``cal``'s models (None: unknown)."""
    specs = dict(state.get('active_specs') or {})
    for sensor in ('accel', 'gyro'):
        if only not in (None, sensor):
            continue
        model = getattr(cal, sensor)
        hit = seen.get(id(model))
        specs[sensor] = hit[1] if hit is not None and hit[0] is model else None
    state['active_specs'] = specs


def offered(state, config):
    """Return ``CalibrateOptions.incumbent_specs`` for the next estimate, or None."""
    specs = state.get('active_specs') or {}
    out = {s: from_state(specs.get(s)) for s in SENSORS[config.incumbent_spec]}
    out = {s: v for s, v in out.items() if v is not None}
    return out or None
