"""Compact statistics of stationary data: sub-windows of holds, as a struct of arrays.

A *hold* is one contiguous stationary segment (one unknown orientation); it is cut into
*windows* of a few seconds so a long hold during warm-up keeps its temperature trend.
Estimators work on these statistics only, never on raw samples, so hours of data fit in
little memory and the live calibrator can persist them line by line (JSON lines).
"""

import json
from dataclasses import dataclass, fields

import numpy as np

FACE_NAMES = ('+x', '-x', '+y', '-y', '+z', '-z')
#: a hold counts as a face when the gravity direction is within this angle of an axis
FACE_TOLERANCE_DEG = 25.0


@dataclass
class Windows:
    """Sub-window statistics; every field has the window count m as leading dimension.

    hold: (m,) int hold id (windows of one hold share an unknown orientation)
    t0, t1: (m,) float window start/end, seconds (header stamps)
    n: (m,) int samples
    accel, gyro: (m, 3) mean m/s^2, rad/s
    accel_var, gyro_var: (m, 3) per-sample variance (within sub-blocks: white noise)
    temp: (m, k) mean temperature per input, degC
    temp_rate: (m, k) temperature rate per input, degC/s
    """

    hold: np.ndarray
    t0: np.ndarray
    t1: np.ndarray
    n: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    accel_var: np.ndarray
    gyro_var: np.ndarray
    temp: np.ndarray
    temp_rate: np.ndarray

    def __len__(self):
        return int(self.hold.shape[0])

    @property
    def n_inputs(self):
        """Return the number of temperature inputs."""
        return int(self.temp.shape[1])

    @staticmethod
    def empty(k=0):
        """Return a table with no windows and k temperature inputs."""
        z3 = np.zeros((0, 3))
        return Windows(np.zeros(0, int), np.zeros(0), np.zeros(0), np.zeros(0, int), z3, z3,
                       z3, z3, np.zeros((0, k)), np.zeros((0, k)))

    def select(self, mask):
        """Return the windows selected by a boolean mask or index array."""
        return Windows(**{f.name: getattr(self, f.name)[mask] for f in fields(self)})

    @staticmethod
    def concat(parts):
        """Concatenate tables (all must have the same number of temperature inputs)."""
        parts = [p for p in parts if len(p)]
        if not parts:
            return Windows.empty()
        return Windows(**{f.name: np.concatenate([getattr(p, f.name) for p in parts])
                          for f in fields(Windows)})

    @property
    def hold_ids(self):
        """Return the distinct hold ids in order of appearance."""
        _, idx = np.unique(self.hold, return_index=True)
        return self.hold[np.sort(idx)]

    def hold_spans(self):
        """Return (``hold_ids``, (h,) first window start (s), (h,) last window end (s))."""
        ids = self.hold_ids
        uniq, inv = np.unique(self.hold, return_inverse=True)
        start = np.full(len(uniq), np.inf)
        end = np.full(len(uniq), -np.inf)
        np.minimum.at(start, inv, self.t0)
        np.maximum.at(end, inv, self.t1)
        at = np.searchsorted(uniq, ids)
        return ids, start[at], end[at]

    def hold_starts(self):
        """Return (``hold_ids``, (h,) the start (s) of each hold's first window)."""
        ids, start, _ = self.hold_spans()
        return ids, start

    def hold_means(self):
        """Return (ids, (h, 3) sample-weighted mean accel per hold)."""
        ids = self.hold_ids
        out = np.zeros((len(ids), 3))
        for j, h in enumerate(ids):
            m = self.hold == h
            out[j] = np.average(self.accel[m], axis=0, weights=self.n[m])
        return ids, out

    def to_jsonl(self):
        """Return one JSON line per window."""
        lines = []
        for i in range(len(self)):
            rec = {f.name: _py(getattr(self, f.name)[i]) for f in fields(self)}
            lines.append(json.dumps(rec, separators=(',', ':')))
        return '\n'.join(lines) + ('\n' if lines else '')

    @staticmethod
    def from_jsonl(text, k=None):
        """Parse ``to_jsonl`` output; a truncated last line (crash mid-write) is skipped."""
        recs = []
        for line in text.splitlines():
            line = line.strip()
            if not line:
                continue
            try:
                recs.append(json.loads(line))
            except json.JSONDecodeError:
                continue
        if not recs:
            return Windows.empty(k or 0)
        cols = {f.name: np.asarray([r[f.name] for r in recs]) for f in fields(Windows)}
        kk = len(recs[0]['temp'])
        cols['temp'] = cols['temp'].reshape(len(recs), kk).astype(float)
        cols['temp_rate'] = cols['temp_rate'].reshape(len(recs), kk).astype(float)
        cols['hold'] = cols['hold'].astype(int)
        cols['n'] = cols['n'].astype(int)
        return Windows(**cols)


def _py(v):
    return v.tolist() if isinstance(v, np.ndarray) else (v.item() if hasattr(v, 'item') else v)


def face_of(direction):
    """Return the face label ('+x' .. '-z') for a unit gravity-up direction, or 'tilted'."""
    u = np.asarray(direction, float)
    u = u / np.linalg.norm(u)
    i = int(np.argmax(np.abs(u)))
    if abs(u[i]) < np.cos(np.radians(FACE_TOLERANCE_DEG)):
        return 'tilted'
    return ('+' if u[i] > 0 else '-') + 'xyz'[i]


def coverage(windows):
    """Summarise what was held: per face the holds, seconds and temperature span.

    Returns a dict: faces -> {holds, seconds, t_min, t_max}, tilted holds, total holds,
    temperature span per input, and ``missing`` faces.
    """
    ids, means = windows.hold_means() if len(windows) else (np.zeros(0, int), np.zeros((0, 3)))
    faces = {f: {'holds': 0, 'seconds': 0.0, 'temp_min': None, 'temp_max': None}
             for f in FACE_NAMES}
    tilted = 0
    for h, m in zip(ids, means):
        sel = windows.hold == h
        face = face_of(m)
        if face == 'tilted':
            tilted += 1
            continue
        rec = faces[face]
        rec['holds'] += 1
        rec['seconds'] += float(np.sum(windows.t1[sel] - windows.t0[sel]))
        if windows.n_inputs:
            tmin = float(windows.temp[sel, 0].min())
            tmax = float(windows.temp[sel, 0].max())
            rec['temp_min'] = tmin if rec['temp_min'] is None else min(rec['temp_min'], tmin)
            rec['temp_max'] = tmax if rec['temp_max'] is None else max(rec['temp_max'], tmax)
    span = None
    if len(windows) and windows.n_inputs:
        span = [[float(windows.temp[:, j].min()), float(windows.temp[:, j].max())]
                for j in range(windows.n_inputs)]
    return {'faces': faces, 'tilted_holds': tilted, 'holds': int(len(ids)),
            'windows': int(len(windows)), 'temperature_span': span,
            'missing': [f for f in FACE_NAMES if faces[f]['holds'] == 0]}


def _directions(windows):
    """Return ((h, 3) unit gravity-up direction, (h,) samples) per hold."""
    _, means = windows.hold_means()
    w = np.array([windows.n[windows.hold == h].sum() for h in windows.hold_ids], float)
    return means / np.linalg.norm(means, axis=1, keepdims=True), w


def _main(u, w, within_deg):
    close = (u @ u.T) > np.cos(np.radians(within_deg))
    ref = u[int(np.argmax(close @ w))]
    m = u @ ref > np.cos(np.radians(within_deg))
    v = w[m] @ u[m]
    return v / np.linalg.norm(v)


def main_direction(windows, within_deg=2.0):
    """Return the gravity-up unit vector of the most common pose (None: no windows).

    The hold whose direction has the most sample weight within ``within_deg`` (degrees) of
    it, then the sample-weighted mean direction of the holds within that angle of it.
    """
    if not len(windows):
        return None
    return _main(*_directions(windows), within_deg)


def family_direction(windows, angle_deg=20.0):
    """Return ``main_direction`` when every hold is within ``angle_deg`` of it, else None.

    One orientation family, measured from the most common pose and not hold to hold: a
    robot on its wheels stopping level and on slopes either way (up to 24 deg apart from
    each other). None for no windows.
    """
    if not len(windows):
        return None
    return _family(*_directions(windows), angle_deg)


def _family(u, w, angle_deg):
    ref = _main(u, w, 2.0)
    return ref if np.all(u @ ref >= np.cos(np.radians(angle_deg))) else None


#: one orientation family: the holds a one-orientation fit uses are those within this angle
#: of the mounting pose (degrees; ``calibrate`` and lifelong mode). A tilt of 1 deg moves
#: g sin(1 deg) = 0.17 m/s^2 onto the horizontal axes, far more than thermal drift, so
#: holds on a slope would read as drift to the one-pose models
MOUNTING_POSE_DEG = 2.0


def mounting_pose_mask(windows, within_deg, reference=None, family_deg=20.0):
    """Return the (n,) bool mask of the windows whose hold is within ``within_deg`` of the pose.

    Only when the holds form one orientation family (``family_direction`` at
    ``family_deg``: a robot on its wheels, level or on slopes, or one pose in a chamber);
    the pose is ``reference`` (a unit gravity-up vector) or the mounting pose
    (``main_direction``). With several orientations, or no windows, every window is kept.
    Angles in degrees.
    """
    everything = np.ones(len(windows), bool)
    if not len(windows):
        return everything
    u, w = _directions(windows)
    ref = _family(u, w, family_deg) if reference is None else reference
    if ref is None:
        return everything
    keep = windows.hold_ids[u @ ref >= np.cos(np.radians(within_deg))]
    return np.isin(windows.hold, keep)


def distinct_orientations(windows, angle_deg=20.0):
    """Count holds whose gravity directions differ by more than ``angle_deg`` from each other.

    One when every hold is within ``angle_deg`` of the most common pose
    (``family_direction``), whatever their order: a robot on its wheels stopping level and
    on slopes either way (counted two hold to hold) is one orientation, as it is with
    slopes one way; the standard fit of several orientations refused it for missing faces.
    """
    _, means = windows.hold_means()
    reps = []
    for m in means:
        u = m / np.linalg.norm(m)
        if all(np.degrees(np.arccos(np.clip(u @ r, -1, 1))) > angle_deg for r in reps):
            reps.append(u)
    if len(reps) > 1 and family_direction(windows, angle_deg) is not None:
        return 1
    return len(reps)


def readable_records(data: bytes, k: int):
    """Return (text of the readable records, records skipped, records seen) of JSON lines.

    ``data`` is a collection file's bytes (``Windows.to_jsonl`` lines). A record (one line)
    is skipped when it is not UTF-8, not JSON or lacks a field the windows table needs, or
    has other than ``k`` thermal inputs; the others are kept (one bad line does not lose the
    collection).
    """
    good, skipped, total = [], 0, 0
    for line in data.splitlines():
        if not line.strip():
            continue
        total += 1
        try:
            text = line.decode('utf-8')
            win = Windows.from_jsonl(text, k)
            if len(win) != 1 or win.n_inputs != k:
                raise ValueError('not one record of this node\'s inputs')
        except Exception:  # noqa: B902 - any bad record is skipped and counted
            skipped += 1
            continue
        good.append(text)
    return '\n'.join(good) + ('\n' if good else ''), skipped, total
