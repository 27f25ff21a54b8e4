"""The gyro offset follower: what the newest holds say the active gyro model misses now.

Between two swaps the gyro bias goes on moving (a slow ageing trend, a knock before its
alarm) while the active model holds the bias of its estimate. Every still hold measures
the model's gyro error directly: its compensated mean less the earth rate. The vertical
part of the earth rate is known from the hold's specific force and the latitude; the
horizontal part (``EARTH_RATE`` cos(lat), 5.2e-5 rad/s at 45 deg) points along the
unknown heading and averages out over holds at different headings, as a robot's stops
are. The follower's offset is the exponentially weighted mean of those errors over the
store's raw holds of the last ``follow_horizon_days`` (weight ``exp(-age /
follow_tau_days)``, equal per hold), once the weights add up to ``follow_min_holds``
effective holds (``(sum w)^2 / sum w^2``); before that, none. ``imu_processors``'
``imu_bias_remover`` re-estimates a bias in the same way whenever the robot is commanded
still, with no temperature model underneath; here it sits on top of the thermal model, so
what it learns at one temperature is only the model's recent miss, not the bias.

It is an output correction only: ``with_offset`` puts it into the published calibration
as ``gyro_ageing.offset`` (file format 5; every stream takes it off the gyro), while the
swap gate, the change alarm and the registry go on judging the model itself, so the
loop's decisions are the same with or without it.

Without the latitude the vertical earth rate cannot be told from a bias. With
``follow_without_latitude`` (the default) the follower then follows in the model's own
convention: a model fitted without the latitude took the vertical earth rate of its holds
into its gyro bias (its output at rest reads about zero, not the earth rate), so its miss
on a hold is the whole compensated mean (what ``imu_bias_remover`` takes off). A model
fitted with the latitude and followed without it would lose the vertical earth rate from
its output (<= 7.3e-5 rad/s); in the loop both use the one setting. Off: without the
latitude it follows nothing.

No ROS import. Units: rad/s, s, days.
"""

from dataclasses import replace

import numpy as np

from ..calibration.base import DAY_S
from . import gate


def follow(cal, windows, gravity, latitude, now, tau_days, horizon_days, min_holds,
           without_latitude=False):
    """Return (offset (3,) rad/s or None, record dict) of ``cal`` on the newest holds.

    ``windows``: the store's raw windows (``collection.segments.Windows``, the holds the
    alarm and the gate see); ``now``: s on their clock (the newest hold's end);
    ``without_latitude``: ``latitude`` None follows in the model's convention (the module
    docstring), else it follows nothing. The record (for the log): time, holds used,
    effective holds, offset (or why none).
    """
    rec = {'time': float(now), 'active': cal.id if cal is not None else ''}
    defined = latitude is not None or without_latitude    # the model's miss is known
    if cal is None or cal.gyro is None or not defined or not len(windows):
        rec['why'] = ('no active gyro model' if cal is None or cal.gyro is None else
                      'no latitude: the vertical earth rate is not known'
                      if not defined else 'no holds')
        return None, rec
    recent = windows.select(windows.t1 >= now - horizon_days * DAY_S)
    if not len(recent):
        rec.update(holds=0, why='no hold within the horizon')
        return None, rec
    e = gate.hold_errors(_model_only(cal), recent, gravity, latitude)
    w = np.exp(-np.maximum(now - e['t'], 0.0) / (tau_days * DAY_S))
    eff = float(w.sum() ** 2 / np.sum(w ** 2))
    rec.update(holds=int(len(w)), effective=round(eff, 2))
    if eff < min_holds:
        rec['why'] = f'{eff:.1f} effective holds, {min_holds:g} needed'
        return None, rec
    offset = w @ e['gyro_vec'] / w.sum()
    rec['offset_rad_s'] = offset.tolist()
    return offset, rec


def output(active, recent, latitude, config):
    """Return (the calibration to publish, the follower's record or None).

    ``active`` with the offset ``follow`` finds on ``recent`` (the store's raw windows,
    ``now`` their newest end) when ``config.gyro_follow`` is on; else ``active`` itself.
    """
    if not config.gyro_follow or active is None:
        return active, None
    now = float(recent.t1.max()) if len(recent) else 0.0
    offset, rec = follow(active, recent, active.gravity, latitude, now,
                         config.follow_tau_days, config.follow_horizon_days,
                         config.follow_min_holds, config.follow_without_latitude)
    return with_offset(active, offset, now, config.follow_horizon_days), rec


def status(published):
    """Return the /diagnostics figures of what is published: its id and offset (rad/s)."""
    if published is None:
        return {'published': ''}
    offset = (published.gyro_ageing or {}).get('offset')
    return {'published': published.id, 'gyro_follow_offset_rad_s':
            float(np.linalg.norm(offset)) if offset is not None else 0.0}


def _model_only(cal):
    """Return ``cal`` without a follower offset (the model the gate and alarm judge)."""
    ag = cal.gyro_ageing
    if not ag or ag.get('offset') is None:
        return cal
    rest = {k: v for k, v in ag.items() if k != 'offset'}
    return replace(cal, gyro_ageing=rest if np.any(rest['rate']) else {})


def with_offset(cal, offset, epoch, horizon_days):
    """Return ``cal`` with the follower's ``offset`` (3,) rad/s taken off its gyro output.

    Kept in ``gyro_ageing.offset``; a calibration without an ageing term gets one with a
    zero rate (``epoch`` s, ``max_days`` the follower's horizon: the rate is zero, so the
    bound changes nothing). ``offset`` None: ``cal`` itself.
    """
    if offset is None or cal is None:
        return cal
    ag = dict(cal.gyro_ageing) if cal.gyro_ageing else {
        'rate': np.zeros(3), 'epoch': float(epoch), 'max_days': float(horizon_days)}
    ag['offset'] = np.asarray(offset, float)
    return replace(cal, gyro_ageing=ag)
