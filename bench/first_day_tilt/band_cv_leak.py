"""Seed 61's one-way band CV (one_way_select.band_folds / level_drift) with and without the
held-out windows' holds in training. Usage: band_cv_leak.py FIT_PKL"""
import os
import pickle
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
from thermal_imu_calib.estimation.hysteresis import Features, fit_spec, predict, Spec, \
    NO_THERMAL_SPEC  # noqa: E402
from thermal_imu_calib.selection.one_way_select import band_folds, level_drift  # noqa: E402

cap = pickle.load(open(sys.argv[1], 'rb'))
w = cap['fit']
t0 = np.full(3, cap['active']['accel']['parameters']['T0']['value'][0])
feats = Features(w, [0, 0, 0])
folds, kind = band_folds(w)
specs = {'no thermal terms': NO_THERMAL_SPEC,
         'quadratic T_lag:2000, temp-w': Spec(2, (2000.0,), (), 'temperature'),
         'quadratic T, temp-w': Spec(2, (), (), 'temperature')}
print(kind)
for train, test, lab in folds:
    hs = np.unique(w.hold[test])
    print(f'{lab}: test windows {test.sum()} from holds {hs.tolist()}; training windows of '
          f'those holds left in: {int(np.sum(train & np.isin(w.hold, hs)))}')
for name, s in specs.items():
    figs = {'as the code (leaky)': [], 'whole holds out of training': []}
    for train, test, _ in folds:
        for key, tr in (('as the code (leaky)', train),
                        ('whole holds out of training',
                         train & ~np.isin(w.hold, np.unique(w.hold[test])))):
            coef, _ = fit_spec(feats, s, w.accel, tr, t0)
            figs[key].append(level_drift(w.accel - predict(feats, s, coef, t0), w, tr, test))
    print(f'{name:32s}', '; '.join(f'{k}: ' + ', '.join(f'{x * 1e3:.1f}' for x in v)
                                   + ' mm/s^2' for k, v in figs.items()))
