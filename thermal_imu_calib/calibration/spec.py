"""The words the calibration schema is written in: a field's type, default and message.

Each spec checks one value of a parsed YAML document and returns it normalised (text as
``str``, numbers as ``float`` or a finite float array, mappings as dicts of their fields),
or raises ValueError naming the field by its path (``accel.parameters.k1.std``), saying
what it must be and what it got. ``Mapping.read`` fills absent fields with their default;
in every field but those built with ``null=False`` an explicit ``null`` counts as absent.
Keys a mapping does not declare are ignored (a newer writer may add some).

Every walk is bounded: numbers and free-form sections are walked iteratively, at most
``MAX_NODES`` values and ``MAX_DEPTH`` levels, so a hostile document costs milliseconds.
"""

import copy
import datetime

import numpy as np

from .base import MAX_DEPTH, MAX_NODES, short, type_name

#: the default of a field that must be present
REQUIRED = object()


def wrong(path, what, value):
    """Return the ValueError 'PATH must be WHAT, got TYPE VALUE'."""
    got = type_name(value) if value is None else f'{type_name(value)} {short(value)}'
    return ValueError(f'{path} must be {what}, got {got}')


class Spec:
    """A field: ``check(value, path)`` returns it normalised or raises ValueError.

    Subclasses define ``_check`` (and ``_absent`` when an absent field is not its default).
    """

    what = 'a value'

    def __init__(self, default=None, null=True):
        self.default, self.null = default, null

    def read(self, d, key, path):
        """Return field ``key`` of mapping ``d`` checked, or its default when absent."""
        if key not in d or (self.null and d[key] is None):
            if self.default is REQUIRED:
                raise ValueError(f'{path} is missing; it must be {self.what}')
            return self._absent(path)
        return self.check(d[key], path)

    def check(self, value, path):
        """Return ``value`` checked and normalised; ValueError naming ``path`` otherwise."""
        return self._check(value, path)

    def _absent(self, path):
        return copy.copy(self.default)    # a copy: defaults are never shared

    def _check(self, value, path):
        return value


class Text(Spec):
    """Text; numbers and dates (YAML reads ``2026-11-22`` as one) are written as text.

    ``numbers=False``: names (a model kind, a unit) must be YAML strings.
    """

    def __init__(self, default='', numbers=True, what='text', **kw):
        super().__init__(default, **kw)
        self.numbers, self.what = numbers, what

    def _check(self, value, path):
        if isinstance(value, str):
            return value
        if self.numbers and not isinstance(value, bool) and isinstance(
                value, (int, float, datetime.date)):
            return str(value)
        raise wrong(path, self.what, value)


class Number(Spec):
    """A finite number as float; ``positive``: > 0; ``within=(lo, hi, why, unit, hint)``."""

    what = 'a number'

    def __init__(self, default=None, positive=False, within=None, **kw):
        super().__init__(default, **kw)
        self.positive, self.within = positive, within

    def _check(self, value, path):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise wrong(path, self.what, value)
        v = float(value)
        if not np.isfinite(v):
            raise ValueError(f'{path} is {v}, not a finite number')
        if self.positive and not v > 0:
            raise ValueError(f'{path} is {v}; it must be > 0')
        if self.within is not None:
            lo, hi, why, unit, hint = self.within
            if not lo <= v <= hi:
                raise ValueError(f'{path} {v} {unit} is not {why} ({lo}..{hi}); {hint}')
        return v


class Numbers(Spec):
    """A finite float array from a number or a regular nested list of numbers.

    ``size``: exactly that many values (returned flat); ``nonnegative``: all >= 0.
    """

    what = 'numbers'

    def __init__(self, default=None, size=None, nonnegative=False, **kw):
        super().__init__(default, **kw)
        self.size, self.nonnegative = size, nonnegative

    def _check(self, value, path):
        stack, seen = [value], 0
        while stack:                   # iterative: a list nested 10^5 deep is refused, fast
            x = stack.pop()
            seen += 1
            if seen > MAX_NODES:
                raise ValueError(f'{path} has too many values')
            if isinstance(x, list):
                stack.extend(x)
            elif isinstance(x, bool) or not isinstance(x, (int, float)):
                raise ValueError(f'{path} must be numbers, found {type_name(x)} {short(x)}')
        try:
            a = np.asarray(value, float)
        except (ValueError, TypeError, OverflowError):
            raise ValueError(f'{path} is not a regular array of numbers (ragged lists?)') \
                from None
        if a.ndim > 4:
            raise ValueError(f'{path} has {a.ndim} dimensions')
        if not np.all(np.isfinite(a)):
            raise ValueError(f'{path} {short(a.tolist())} is not finite (non-finite values '
                             'are refused)')
        if self.size is not None:
            if a.size != self.size:
                raise ValueError(f'{path} {short(a.tolist())} has {a.size} values, expected '
                                 f'{self.size} (one per axis)')
            a = a.reshape(self.size)
        if self.nonnegative and np.any(a < 0):
            raise ValueError(f'{path} {short(a.tolist())} is negative; it must be >= 0')
        return a


class Choice(Spec):
    """One of a few names."""

    def __init__(self, options, default=None, **kw):
        super().__init__(default, **kw)
        self.options = tuple(options)
        self.what = f'one of {self.options}'

    def _check(self, value, path):
        if not isinstance(value, str) or value not in self.options:
            raise ValueError(f'{path} {short(value)} is not one of {self.options}')
        return value


class Indices(Spec):
    """A list of ``n`` integer indices (YAML booleans are not indices)."""

    def __init__(self, n, default=None, **kw):
        super().__init__(default, **kw)
        self.n, self.what = n, f'a list of {n} input indices'

    def _check(self, value, path):
        if not isinstance(value, list) or len(value) != self.n or not all(
                isinstance(i, int) and not isinstance(i, bool) for i in value):
            raise wrong(path, self.what, value)
        return [int(i) for i in value]


class Mapping(Spec):
    """A mapping of declared fields ``{key: spec}``; ``rule(checked, path)`` may add checks.

    Absent, it is ``{}`` with its fields' defaults (``optional=True``: absent is None).
    """

    def __init__(self, fields, what='a mapping', rule=None, optional=False, **kw):
        super().__init__(**kw)
        self.fields, self.what, self.rule, self.optional = fields, what, rule, optional

    def _absent(self, path):
        return None if self.optional else self.check({}, path)

    def _check(self, value, path):
        if not isinstance(value, dict):
            raise wrong(path, self.what, value)
        out = {key: spec.read(value, key, f'{path}.{key}' if path else key)
               for key, spec in self.fields.items()}
        if self.rule is not None:
            self.rule(out, path)
        return out


class MapOf(Spec):
    """A non-empty mapping of names to one spec (a model's parameters)."""

    def __init__(self, item, what='a non-empty mapping', **kw):
        super().__init__(REQUIRED, **kw)
        self.item, self.what = item, what

    def _check(self, value, path):
        if not isinstance(value, dict) or not value:
            raise wrong(path, self.what, value)
        for key in value:
            if not isinstance(key, str):
                raise ValueError(f'{path}: key {short(key)} is not a name')
        return {key: self.item.check(v, f'{path}.{key}') for key, v in value.items()}


class ListOf(Spec):
    """A list whose items are all of one spec (absent: an empty list)."""

    what = 'a list'

    def __init__(self, item, **kw):
        super().__init__(None, **kw)
        self.item = item

    def _absent(self, path):
        return []

    def _check(self, value, path):
        if not isinstance(value, list):
            raise wrong(path, self.what, value)
        return [self.item.check(v, f'{path}[{j}]') for j, v in enumerate(value)]


class TextOrList(Spec):
    """Text, or a list of text (a unit for every input, or one per input)."""

    what = 'text or a list of text'

    def _check(self, value, path):
        items = value if isinstance(value, list) else [value]
        if not all(isinstance(u, str) for u in items):
            raise wrong(path, self.what, value)
        return value


class Valued(Spec):
    """A ``{value: ..., unit: ...}`` entry, or its bare value; returns the value checked."""

    def __init__(self, item, **kw):
        super().__init__(None, **kw)
        self.item, self.what = item, f'{item.what} or a mapping with value'

    def _check(self, value, path):
        if isinstance(value, dict):
            return self.item.read(value, 'value', f'{path}.value')
        return self.item.check(value, path)


class FreeForm(Spec):
    """A section of plain data of any shape (``fit``, a model's ``meta``).

    Its type is checked and its content bounded (at most MAX_NODES values, MAX_DEPTH
    levels, plain YAML scalars only); it is returned unchanged. Absent, it is empty
    (``optional=True``: None).
    """

    def __init__(self, kind, optional=False, **kw):
        super().__init__(**kw)
        self.kind, self.optional = kind, optional
        self.what = 'a mapping' if kind is dict else 'a list'

    def _absent(self, path):
        return None if self.optional else self.kind()

    def _check(self, value, path):
        if not isinstance(value, self.kind):
            raise wrong(path, self.what, value)
        stack, seen = [(value, 0)], 0
        while stack:
            v, depth = stack.pop()
            seen += 1
            if seen > MAX_NODES or depth > MAX_DEPTH:
                raise ValueError(f'{path} is too large or too deeply nested')
            if isinstance(v, dict):
                stack.extend((w, depth + 1) for kv in v.items() for w in kv)
            elif isinstance(v, (list, tuple)):
                stack.extend((w, depth + 1) for w in v)
            elif not isinstance(v, (str, int, float, bool, type(None), datetime.date,
                                    np.generic, np.ndarray)):
                raise ValueError(f'{path} holds {type_name(v)}, not plain data')
        return value


class Notes(FreeForm):
    """A list of notes of plain data, or one note as text; returned as a list of text."""

    def __init__(self):
        super().__init__(list)
        self.what = 'a list or text'

    def _check(self, value, path):
        notes = [value] if isinstance(value, str) else super()._check(value, path)
        return [str(n) for n in notes]
