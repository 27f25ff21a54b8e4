"""When the lifelong loop re-estimates, how sure a swap must be, what the alarm watches.

``LifelongConfig`` holds the lifelong loop's settings (degC, holds, sigmas, degrees) and
refuses, on construction, a value the loop cannot run with; each field says what it does
and, for the choices, what the simulated robot months showed (docs/lifelong.md). No ROS
import.
"""

from dataclasses import dataclass, field

import numpy as np

from ..collection.segments import MOUNTING_POSE_DEG
from ..estimation.options import HIGH_ORDER_SENSORS
from . import gate
from .store import StoreConfig


@dataclass
class LifelongConfig:
    """When to re-estimate and how sure a swap must be (degC, holds, sigmas)."""

    range_extension_degc: float = 3.0
    new_holds: int = 40
    holdout_holds: int = 8
    min_holds: int = 6
    swap_sigmas: float = 2.0
    alarm_holds: int = 5
    alarm_factor: float = 5.0
    alarm_floor: float = 5.0
    #: new holds the active misses (``gate.misses``) that make a re-estimate due
    misfit_holds: int = 2
    #: one orientation family: fit only the holds within this angle of the mounting pose
    pose_deg: float = MOUNTING_POSE_DEG
    #: also fit with the gyro ageing removed, kept when held-out holds prefer it (``ageing``)
    ageing: bool = True
    #: a new estimate better for one sensor only replaces that sensor's model alone
    #: (``compose``); False: the whole calibration or nothing
    per_sensor: bool = True
    #: no swap to a calibration that misses ``misfit_holds`` of the held-out holds by the
    #: change alarm's gyro limit (they say the sensor changed;
    #: ``gate.unexplained``). On since 2026-12-06: judged on four months no
    #: run had seen (165-168) at the default of that day, it caught a knock the default
    #: missed and harmed nothing (gyro last week / true model -20 %; docs/lifelong.md). It
    #: was off after its first judgement (seed 4, 2026-11-28, an older default)
    swap_must_explain: bool = True
    #: which holds the change alarm watches: 'common', those inside both sensors' valid
    #: range (``compose.common_range``); 'sensor', each sensor's holds inside its own range
    #: (after one-sensor swaps the common range narrows and a knock is seen later)
    alarm_window: str = 'common'
    #: whose own ranges bound the common range (``compose.common_range``: the change
    #: alarm's window, the range extension that makes a re-estimate due, diagnostics):
    #: 'every' sensor's; 'thermal', only those whose model depends on temperature (a model
    #: without temperature terms kept from a few cold holds narrowed the window so that the
    #: knock's holds fell outside it: seeds 59 and 61, docs/lifelong.md). 'every': on
    #: seeds 132-134 (unseen) it did not act, so nothing was judged; it belongs with
    #: ``placement_floor``, whose degree-0 models it is for, and the pair missed on seeds
    #: 135-136 (last-week accelerometer drift +6.9 %, one more swap worse next day)
    range_sensors: str = 'every'
    #: after a change alarm, a new estimate better for one sensor only also replaces that
    #: sensor alone (False: after an alarm the whole new calibration is judged; on seeds 0-5
    #: the first swap after the knock then took an accelerometer fitted on the few holds
    #: after the cut, and the next day's accel drift was 1.5-32x worse). Judged again on
    #: seeds 179-181 (2026-12-07, with the shifted cut): swaps worse next day 3 -> 2, but
    #: the last week's accel drift +41 % (the pre-knock accelerometer kept longer): off
    one_sensor_after_alarm: bool = False
    #: the holds a swap measures the change alarm's new reference on: 'all' (the raw holds
    #: it was fitted on and the held-out ones), or 'explained' (of those, the ones the new
    #: calibration does not miss by the alarm's limit against the old reference; a
    #: reference measured on holds of a changed sensor hides the change: seeds 2, 9, 19).
    #: Off: on seeds 9-11 (unseen) it brought seed 9's missing knock alarm (2.7 h) and the
    #: gyro 35 % closer to the true model, but the accelerometer drift 26 % worse, past the
    #: 10 % set before the runs (docs/lifelong.md)
    alarm_reference: str = 'all'
    #: no re-estimate but the alarm's own while the change alarm is deciding: a sensor's
    #: newest tracked holds all miss its limit, fewer than ``alarm_holds`` of them, and
    #: fewer than ``alarm_holds`` holds came in since the first (``trigger.due``,
    #: ``alarm.pending_since``). Adds no threshold: the alarm's limit and hold count. Off:
    #: it brought seed 52's missing knock alarm (2.7 h), but on seeds 54-56 (unseen;
    #: criteria written before the runs) the accelerometer drift of the last week was 6.9 %
    #: worse (past the 5 % set) and swaps with a worse next day 7 -> 8 (docs/lifelong.md)
    alarm_first: bool = False
    #: calibrate with ``CalibrateSettings.placement_folds``: every stop is a separate
    #: placement, so the held-out folds that choose the thermal model (one orientation)
    #: never keep a test hold's other windows in training (docs/lifelong.md, "The first
    #: estimate reads floor tilt as temperature"). Being judged, off
    placement_folds: bool = False
    #: calibrate with ``CalibrateSettings.placement_floor``: a sensor's thermal model must
    #: also be no worse than its output as it is when whole stops are left out; else that
    #: sensor gets no thermal terms. Off: with ``range_sensors='thermal'`` it met its
    #: criteria on seeds 132-134 (first day -26 %, the rest the same), but without it the
    #: floor's degree-0 accelerometer narrowed seed 61's alarm window and lost the knock
    #: alarm. The pair, judged on seeds 135-136: first day -39 %, but the last week's
    #: accelerometer drift +6.9 % and one more swap worse next day (docs/lifelong.md)
    placement_floor: bool = False
    #: calibrate with ``CalibrateSettings.placement_levels``: in the thermal-history fits
    #: each stop's level is a random effect (REML), so floor tilt and heading that differ
    #: from stop to stop are not read as temperature (docs/lifelong.md, "A random level
    #: per stop"). On, for the accelerometer (``placement_levels_sensors``): on seeds
    #: 137-138 (unseen; criteria written before the runs) the first day's accelerometer
    #: drift -29 %, the last week's -53 %, gyro last/true -11 %, the same swaps worse next
    #: day and the same alarms. For both sensors it missed on seeds 135-136 (swaps with a
    #: worse next day 1 -> 3; the gyro beyond its range learned later)
    placement_levels: bool = True
    #: the sensors ``placement_levels`` applies to: 'both', 'accel' or 'gyro'
    placement_levels_sensors: str = 'accel'
    #: what a change alarm cuts: 'all' (every hold before it, for both sensors) or
    #: 'sensor' (when one sensor alone failed, its history only: the other keeps the
    #: older holds for its fits, ``HoldStore.cut(keep=...)``, ``variants.with_kept``; an
    #: alarm of both cuts both). Off: on seeds 7, 8 and 12 (unseen) it never acted, every
    #: knock's alarm flagged both sensors (the simulated knock steps both; docs/lifelong.md).
    #: 'shift' (the default): the holds before the change are moved by the step of both
    #: sensors' biases the holds after the alarm show against the active calibration
    #: (``knock_step``, ``HoldStore.shift``; a knock moves offsets, not the thermal
    #: sensitivity, so the estimate after the alarm keeps the whole temperature span).
    #: Several poses, or no step measurable: cut as 'all'. On seeds 25-30 (unseen; criteria
    #: written before the runs) gyro last/true -13 % and -5 %, accel drift +4 % and -27 %,
    #: swaps with a worse next day 6 -> 2 and 6 -> 5, the same alarms (docs/lifelong.md)
    alarm_cut: str = 'shift'
    #: how the swap gate measures the accelerometer on held-out holds
    #: (``gate.ACCEL_SCORES``): 'magnitude', |mean accel| - g about the median, blind to the
    #: horizontal axes in a level mounting pose; 'vector', the whole mean vector about the
    #: per-axis median, the floor's tilt in its scatter. 'magnitude' stays: on seeds 2-4
    #: (unseen) 'vector' alone left the first day's accelerometer as it was (the gyro's gain
    #: still carries a first estimate in whole; docs/lifelong.md)
    accel_score: str = 'magnitude'
    #: with no active calibration, a new estimate better than the raw output for one sensor
    #: only replaces that sensor's raw output alone; the other stays raw (a calibration
    #: without its model) until an estimate is proven better for it (``compose.one_sensor``).
    #: Off: on seeds 5-7 (unseen), with 'vector', the first day's accelerometer drift halved
    #: (raw's), but the last week's was 66 % worse and seed 7 had two false alarms
    #: (docs/lifelong.md)
    raw_kept: bool = False
    #: a swap activates the estimate fitted again with the same choices on every hold, the
    #: held-out ones too (``variants.refit``); False: the estimate the gate judged, whose
    #: fit left out the newest holds, often the very temperatures that made it due
    refit_on_swap: bool = False
    #: the gyro also takes the g-sensitivity learned from the holds off the mounting pose
    #: (slopes), paired with level holds near in time, when the newest of them, held out,
    #: support it (``g_sensitivity``). On: on seeds 44-48 (unseen; criteria written before
    #: the runs) gyro last/true -16 %, accel drift the same, swaps with a worse next day
    #: 4 -> 2, the same alarms (docs/lifelong.md)
    gyro_g_sensitivity: bool = True
    #: beyond its valid range the gyro of a new estimate: 'off', as the calibrate settings
    #: say (``out_of_range``, clamp by default); 'history', continued linearly when the
    #: holds outside the earlier active calibrations' ranges, held out, say continuing
    #: beats clamping, else clamped (``continuation``). 'history' since 2026-12-06: on
    #: seeds 158-160 (unseen; criteria written before the runs) all six criteria met:
    #: the stops beyond the range -49 %, gyro last/true -34 %, accel drift -15 %, swaps
    #: with a worse next day 5 -> 3, the same alarms, no harmful swap on the real
    #: recordings. Earlier: seeds 44-48 and 139-140 missed by one swap each (a timing of
    #: the same swap on 139), 137-138 met (docs/lifelong.md). A verdict without the holds
    #: both policies miss by the alarm's limit was judged on seed 183 (2026-12-07): no
    #: gain, and it does not act on 175 and 178, whose first-day rows keep them clamped.
    #: 'span': as 'history', on the rows of calibrations spanning at least half the new
    #: estimate's span (``continuation.like``). Not adopted: on seeds 192 and 194 (unseen;
    #: criteria written before the runs) every figure the same to the printed digit (gyro
    #: last/true 1.173 both, 5 % better asked), two swaps fewer on 194
    gyro_continuation: str = 'history'
    #: an estimate kept with its gyro ageing removed (``ageing``) carries the resolved rates
    #: forward in time in its file (``Calibration.gyro_ageing``: from the estimate's time,
    #: at most the span the rates were measured over); False: the file holds the bias of
    #: the estimate's time until the next swap. Off: on seeds 145-148 (unseen; criteria
    #: written before the runs) gyro last/true -14.9 % and the accelerometer and alarms the
    #: same, but swaps with a worse next day 3 -> 5 (docs/lifelong.md)
    gyro_ageing_forward: bool = False
    #: when the gate keeps the active gyro, the held-out gyro errors of the successive
    #: estimates are pooled (each hold once) and judged by the gate's rule with the noise
    #: floor of the pool's size (``pooled``); 'better' swaps the candidate's gyro alone.
    #: Off: on seeds 161-164 (unseen; criteria written before the runs) gyro last/true
    #: -3.5 % (10 % asked), accel drift +8.1 % and swaps with a worse next day 5 -> 6
    #: (docs/lifelong.md)
    gyro_pooled_gate: bool = False
    #: the published calibration takes off the gyro what the newest holds say the active
    #: model misses now (``follower``: an exponentially weighted mean of their errors, the
    #: known vertical earth rate removed; needs the latitude); an output correction only,
    #: the gate, the alarm and the registry judge the model. On since 2026-12-07: on seeds
    #: 169-172 (unseen; criteria written before the runs) gyro last/true -30 % (every month
    #: better, 0 -> 4 of 4 within 1.5x), the second day after the knock -49 %, the first
    #: day -2.6 % (docs/lifelong.md, "The gyro's recent miss followed")
    gyro_follow: bool = True
    #: the follower's time constant and horizon (days) and the effective holds it needs
    follow_tau_days: float = 0.5
    follow_horizon_days: float = 2.0
    follow_min_holds: float = 5.0
    #: without a latitude the follower follows in the model's own convention (a model
    #: fitted without it holds the vertical earth rate in its gyro bias, so its miss is
    #: the whole compensated mean; ``follower``); off: without a latitude it follows
    #: nothing. On since 2026-12-07: on seeds 173-176 run without a latitude (unseen;
    #: criteria written before the runs) gyro last/true -24.5 % (every month better, 1 ->
    #: 3 of 4 within 1.5x), the second day after the knock -42 %, the first day -0.6 %;
    #: the real chamber log -0.6 % (docs/lifelong.md, "The follower without a latitude")
    follow_without_latitude: bool = True
    #: the thermal spec of the model in use is offered to the next estimate, which keeps it
    #: whenever held-out blocks put it within the margin of the best (``incumbent``):
    #: 'off', 'accel' or 'both'. Not adopted: on seeds 198 and 199 (unseen; criteria
    #: written before the runs) accel drift last week -10.9 %, but gyro last/true +7.4 %
    #: (5 % allowed) and swaps worse next day 2 -> 2 (fewer asked); docs/lifelong.md
    incumbent_spec: str = 'off'
    #: a swap the gate passes waits for this many holds collected after its estimate and
    #: takes effect only when they favour it too (``prequential``); 0: at once. Not without
    #: an active calibration nor after a change alarm. Not adopted: on seed 207 (unseen;
    #: criteria written before the runs) the knock was never alarmed, since the refused
    #: accel-only swaps left the alarm's common range at the first day's; docs/lifelong.md
    prequential_holds: int = 0
    store: StoreConfig = field(default_factory=StoreConfig)

    def __post_init__(self):
        """Refuse a setting the loop cannot run with, saying which and what to give."""
        for name, allowed in (('alarm_window', ALARM_WINDOWS),
                              ('range_sensors', RANGE_SENSORS),
                              ('alarm_reference', ALARM_REFERENCES),
                              ('alarm_cut', ALARM_CUTS),
                              ('accel_score', gate.ACCEL_SCORES),
                              ('gyro_continuation', GYRO_CONTINUATIONS),
                              ('incumbent_spec', INCUMBENT_SPECS),
                              ('placement_levels_sensors', tuple(HIGH_ORDER_SENSORS))):
            if getattr(self, name) not in allowed:
                raise ValueError(f'LifelongConfig.{name} {getattr(self, name)!r} is not one '
                                 f'of {", ".join(allowed)}; give one of them')
        least = {'new_holds': 1, 'holdout_holds': 2, 'min_holds': 1, 'alarm_holds': 1,
                 'misfit_holds': 1, 'prequential_holds': 0}
        for name, lo in least.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise ValueError(f'LifelongConfig.{name} is {v!r}; give a whole number of '
                                 f'holds, at least {lo}')
        for name in ('range_extension_degc', 'swap_sigmas', 'alarm_factor', 'alarm_floor',
                     'pose_deg', 'follow_tau_days', 'follow_horizon_days', 'follow_min_holds'):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.floating)) or not np.isfinite(v) or v <= 0:
                raise ValueError(f'LifelongConfig.{name} is {v!r}; give a finite number '
                                 'above 0')


#: the values of ``LifelongConfig.alarm_window``, ``alarm_reference`` and ``alarm_cut``
ALARM_WINDOWS = ('common', 'sensor')
#: ``LifelongConfig.range_sensors``
RANGE_SENSORS = ('every', 'thermal')
ALARM_REFERENCES = ('all', 'explained')
ALARM_CUTS = ('all', 'sensor', 'shift')
#: ``LifelongConfig.gyro_continuation``
GYRO_CONTINUATIONS = ('off', 'history', 'span')
#: ``LifelongConfig.incumbent_spec``
INCUMBENT_SPECS = ('off', 'accel', 'both')
