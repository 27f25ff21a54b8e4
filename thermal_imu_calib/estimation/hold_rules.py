"""Leaving holds out of the accelerometer fit: the pose-repeat rule and who judges it.

``hold_consistency`` finds holds whose output changed between visits of the same pose
(handling, a temperature step, sensor-state epochs); ``leave_out_holds`` asks
``HOLD_RULE_JUDGE[0]`` whether leaving them out stands (``selection/static_select`` judges
it held out, against the standard fit) and marks the accelerometer's rows of the Context.
The holds stay in the windows for the gyro and the pose changes. ``consistency_notes``
says what was left out and why.
"""

import numpy as np

from .hold_consistency import hold_consistency


def _apply_hold_rule(ctx, keep):
    """Return (applied, report) for a rule leaving holds out; replaced by held-out judging."""
    return True, {}


#: ``fn(ctx, keep) -> (applied, report)``: whether a rule's leaving out ``~keep`` stands
#: (``selection/static_select.judge_rule``: held out, against the standard fit)
HOLD_RULE_JUDGE = [_apply_hold_rule]


def _no_magnitudes(ctx):
    """Return None: the pose-repeat test then uses its own rough bias and scale fit."""
    return None


#: ``fn(ctx) -> (holds,) |a| of each hold mean after a calibration of all holds, or None``
#: (installed by ``standard_fit``: the standard fit)
HOLD_MAGNITUDES = [_no_magnitudes]


def leave_out_holds(ctx):
    """Apply the pose-repeat rule to ``ctx`` (sets ``accel_rows``); return its report.

    The report is ``hold_consistency``'s, with ``heldout`` (the judge's report) when holds
    disagree, and their list moved to ``not_applied`` when the judge does not support
    leaving them out.
    """
    keep, consistency = hold_consistency(ctx.windows, ctx.options.gravity,
                                         ctx.ta if ctx.k else None,
                                         magnitudes=HOLD_MAGNITUDES[0](ctx))
    if not np.all(keep):
        applied, consistency['heldout'] = HOLD_RULE_JUDGE[0](ctx, keep)
        if applied:
            ctx.accel_rows = keep
        else:
            consistency['not_applied'] = consistency.pop('left_out')
            consistency['left_out'] = []
    return consistency


def consistency_notes(report):
    """Return the notes on the holds ``hold_consistency`` left out of the accel fit."""
    held = report.get('heldout', {})
    if report.get('not_applied'):
        holds = ', '.join(str(h['hold']) for h in report['not_applied'])
        return [f'pose-repeat test: holds {holds} disagree with a visit of the same pose '
                f'(fit.hold_consistency), but they are not left out: '
                f'{held.get("text", "held-out holds do not support it")}']
    out = []
    for h in report['left_out']:
        if 'epoch' in h:
            continue
        out.append(
            f'hold {h["hold"]} left out of the accelerometer fit: still, but its |a| differs '
            f'by {h["difference_ug"]:.0f} ug ({h["z"]:.1f} sigma, limit '
            f'{report["z_limit"]:.1f}) from hold {h["reference_hold"]} in the same pose, so '
            'the sensor output changed between the two (handling, a temperature step); '
            'it is still used for the gyro')
    for k, ep in enumerate(report.get('epochs', [])):
        held = [h['hold'] for h in report['left_out'] if h.get('epoch') == k]
        poses = ', '.join(f'{p["difference_ug"]:.0f} +- {p["sigma_ug"]:.0f} ug'
                          for p in ep['tail_poses'])
        tail = (f'the later repeat visits differ from the earlier holds by {poses} (chi2 '
                f'{ep["tail_chi2"]:.1f} on {ep["tail_dof"]} poses, p {ep["tail_p"]:.2g}: '
                f'the change {"lasted" if ep["lasting"] else "is not shown to last"})'
                if ep['tail_dof'] else 'no later repeat visit to test whether it lasted')
        if not held:
            out.append(f'sensor-state change at hold {ep["holds"][0]}: {tail}; only the '
                       'visits that disagree are left out')
            continue
        obs = ep['observability']
        out.append(f'sensor-state epochs: the output changed by hold {ep["holds"][0]} and '
                   f'{tail}; holds {", ".join(map(str, ep["holds"]))} are one epoch, the '
                   f'{ep["accel_uses"]} one observes more of a bias and scale per axis (rank '
                   f'{obs["earlier"][0]} earlier, {obs["changed"][0]} changed), so holds '
                   f'{", ".join(map(str, held))} are left out of the accelerometer fit; they '
                   'are still used for the gyro')
    if out and held.get('text'):
        out.append(f'pose-repeat test: the holds above are left out because {held["text"]}')
    return out
