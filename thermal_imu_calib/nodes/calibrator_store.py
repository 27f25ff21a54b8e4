"""The calibrator node's collection on disk: the file of closed holds, its pose changes, resume.

``CollectionStore`` is mixed into ``nodes.calibrator_collection.LiveCollection`` (and so
into ``CalibratorNode``): each closed hold's window statistics are appended to
``collection_file`` (JSON lines, fsynced), each pose change between holds is one ``.npz`` in
``<collection_file>.transitions/``, and ``<collection_file>.inputs.json`` says which thermal
inputs (topics, units) the windows' temperature columns are. A restarted node resumes them
(``_resume``, ``_resume_transitions``); a file of other inputs, or one that cannot be read,
is moved aside (``_move_aside``), never deleted; a file that cannot be written leaves the
collection in memory only (``_degrade``). Times: IMU header stamps (s in the windows).
"""

import io
import json
import os
import time

from ..collection.motion import load_transitions, save_transitions
from ..collection.segments import readable_records, Windows
from ..io.output import free_name, OutputError, write_atomic


class CollectionStore:
    """The collection file, its pose changes and inputs (a mixin: it uses the node's logger)."""

    def _collection_path(self):
        if getattr(self, '_collection_error', None):
            return ''
        return os.path.expanduser(self.collection_file) if self.collection_file else ''

    def _transitions_dir(self):
        path = self._collection_path()
        return path + '.transitions' if path else ''

    def _inputs_signature(self):
        """Return what the collected windows' thermal columns mean (topics and units)."""
        return {'temperature_topics': list(self.temperature_topics),
                'temperature_units': list(self.temperature_units)}

    def _write_inputs_signature(self):
        path = self._collection_path()
        if path:
            try:
                os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
                write_atomic(path + '.inputs.json',
                             json.dumps(self._inputs_signature(), indent=1) + '\n')
            except (OSError, OutputError) as e:
                self._degrade(e)

    def _signature_mismatch(self, path):
        """Return why the collection at ``path`` has other thermal inputs (None: same)."""
        try:
            with open(path + '.inputs.json') as f:
                old = json.load(f)
        except FileNotFoundError:
            return None                  # written by an older version: only k is checked
        except (OSError, ValueError) as e:
            return f'its {path}.inputs.json is unreadable ({e})'
        new = self._inputs_signature()
        if old != new:
            return (f'it was collected with temperature inputs {old.get("temperature_topics")} '
                    f'in {old.get("temperature_units")}, this node has '
                    f'{new["temperature_topics"]} in {new["temperature_units"]}')
        return None

    def _resume(self):
        try:
            self._resume_file()
        except (OSError, OutputError) as e:
            self._degrade(e)

    def _degrade(self, err):
        """Collect in memory only when the collection file cannot be read or written."""
        path = self._collection_path()
        self._collection_error = f'{err.__class__.__name__}: {err}'
        self.get_logger().error(f'collection file {path} cannot be used ({err}); collecting '
                                'in memory only (set collection_file to a writable path to '
                                'keep the collection across restarts)')

    def _resume_file(self):
        path = self._collection_path()
        if not path or not os.path.exists(path):
            self._write_inputs_signature()
            return
        with open(path, 'rb') as f:
            data = f.read()
        text, skipped, total = readable_records(data, self.k)
        try:
            win = Windows.from_jsonl(text, self.k)
            if total and not skipped and len(win) == 0:
                raise ValueError('no record could be read')
            if total and skipped == total:
                raise ValueError(f'none of its {total} records could be read')
        except (KeyError, TypeError, ValueError, IndexError) as e:
            win, why = None, f'unreadable ({e.__class__.__name__}: {e})'
        else:
            if skipped:
                self.get_logger().warning(f'collection file {path}: skipped {skipped} of '
                                          f'{total} records that could not be read (not '
                                          'UTF-8, not JSON, or missing a field)')
            why = (None if len(win) == 0 or win.n_inputs == self.k else
                   f'it has {win.n_inputs} temperature inputs, this node {self.k}')
            why = why or self._signature_mismatch(path)
        if why:
            aside = self._move_aside('incompatible')
            self._write_inputs_signature()
            self.get_logger().error(f'collection file {path} not resumed: {why}; moved to '
                                    f'{aside}, starting a new collection')
            return
        self.windows = win
        self._resumed_until = float(win.t1.max()) if len(win) else None
        self.resumed_holds = len(win.hold_ids)
        self._hold_offset = int(win.hold.max()) + 1 if len(win) else 0
        # rewrite only the complete records, so appends never follow a torn last line
        write_atomic(path, win.to_jsonl())
        self._write_inputs_signature()
        self.get_logger().info(f'resumed {len(win)} windows ({len(win.hold_ids)} holds) from '
                               f'{path}')

    def _move_aside(self, tag):
        """Rename the collection file (and its pose changes and inputs) to ``PATH.TAG-TIME[-N]``.

        Returns the new name ('' when there is no file, or it could not be moved: then the
        collection continues in memory only, ``_degrade``).
        """
        path = self._collection_path()
        if not path or not os.path.exists(path):
            return ''
        aside = free_name(f'{path}.{tag}-{int(time.time())}', ('.transitions', '.inputs.json'))
        try:
            os.replace(path, aside)
            tdir = self._transitions_dir()
            if os.path.isdir(tdir):
                os.replace(tdir, aside + '.transitions')
            if os.path.exists(path + '.inputs.json'):
                os.replace(path + '.inputs.json', aside + '.inputs.json')
        except OSError as e:
            self._degrade(e)
            return ''
        return aside

    def _resume_transitions(self):
        """Load the pose changes persisted next to the collection file.

        Those whose holds were not resumed (killed between the two writes) are removed: the
        next holds reuse their ids. Unreadable files are renamed ``*.unreadable``.
        """
        tdir = self._transitions_dir()
        if not tdir or not os.path.isdir(tdir):
            return
        holds = set(self.windows.hold_ids.tolist())
        kept, stale = [], 0
        for name in sorted(os.listdir(tdir)):
            path = os.path.join(tdir, name)
            if name.startswith('.'):     # a temporary file of a write that was cut short
                os.unlink(path)
                continue
            if not name.endswith('.npz'):
                continue
            try:
                trs = load_transitions(path)
            except ValueError as e:
                os.replace(path, path + '.unreadable')
                self.get_logger().error(f'pose change not resumed: {e}; renamed to '
                                        f'{path}.unreadable (one pose change lost)')
                continue
            if all(t.hold_from in holds and t.hold_to in holds and len(t.temps) == self.k
                   for t in trs):
                kept.extend(trs)
            else:
                stale += 1
                os.unlink(path)
        self.transitions = sorted(kept, key=lambda t: t.hold_to)[:self.max_transitions]
        self.get_logger().info(f'resumed {len(self.transitions)} pose changes from {tdir}' + (
            f' ({stale} removed: their holds were not in the collection file)' if stale
            else ''))

    def _persist(self, win):
        path = self._collection_path()
        if not path:
            return
        try:
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            with open(path, 'a') as f:
                f.write(win.to_jsonl())
                f.flush()
                os.fsync(f.fileno())
        except OSError as e:
            self._degrade(e)

    def _persist_transition(self, tr):
        tdir = self._transitions_dir()
        if not tdir:
            return
        try:
            os.makedirs(tdir, exist_ok=True)
            buf = io.BytesIO()
            save_transitions(buf, [tr])
            write_atomic(os.path.join(tdir, f'{tr.hold_from:06d}-{tr.hold_to:06d}.npz'),
                         buf.getvalue())
        except (OSError, OutputError) as e:
            self._degrade(e)
