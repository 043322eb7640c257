"""One validation mechanism for everything a user types: scenario files (``sim``), the paper's
presets, campaign specs (``campaigns``) and the numbers of the command line (``cli``).

A *rule* checks one value and says what it expected (:class:`Number`, :class:`Integer`,
:class:`Flag`, :class:`OneOf`, :class:`Text`, :class:`Pair`, :class:`Seq`, :class:`Maybe`,
:class:`Either`); a frozen dataclass carries its rules in its annotations
(``horizon: Annotated[int, Integer(1)] = 7``; a plain ``float``, ``int``, ``bool`` or ``str`` gets
the type's rule), :func:`check_fields` applies them in ``__post_init__`` and :func:`load` builds the
dataclass from a table (TOML, YAML) naming where each key stands (:class:`InFile`,
:class:`Dotted`). Every refusal is a :class:`SchemaError` whose message has one line per error,
each naming the file, section and key and what was expected; a misspelled key gets the key meant::

    unknown key 'horizn' in [control] of kerb-gap.toml: did you mean 'horizon'?
    dt in [control] of kerb-gap.toml must be a number > 0, got 'fast'

The package imports nothing of trustnav (docs/architecture.md, "One validation mechanism").
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import itertools
import math
import numbers
import re
import types
import typing
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Protocol, Union, get_args, get_origin

__all__ = [
    "Dotted",
    "Either",
    "Flag",
    "InFile",
    "Integer",
    "Invalid",
    "Maybe",
    "Number",
    "OneOf",
    "Pair",
    "Place",
    "Rule",
    "SchemaError",
    "Seq",
    "Text",
    "bad",
    "check_fields",
    "check_keys",
    "did_you_mean",
    "load",
    "load_each",
    "rules_of",
]


class SchemaError(ValueError):
    """Input that does not validate. ``errors``: one line each, naming where and what was expected;
    ``str()`` is the lines joined by newlines."""

    def __init__(self, errors: str | Iterable[str]) -> None:
        self.errors: tuple[str, ...] = (errors,) if isinstance(errors, str) else tuple(errors)
        super().__init__("\n".join(self.errors))


class Invalid(ValueError):
    """Raised by a rule: ``expected`` (what the rule accepts), the ``value`` it got and ``at``
    (an index inside the value, e.g. ``[1]`` of a list; empty for the value itself)."""

    def __init__(self, expected: str, value: Any, at: str = "") -> None:
        self.expected, self.value, self.at = expected, value, at
        super().__init__(f"expected {expected}, got {shown(value)}")


def shown(value: Any) -> str:
    """A value as an error message quotes it: repr, with ``inf`` and ``nan`` as TOML writes them."""
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return repr(value)


class Rule(Protocol):
    """A check of one value: returns the value (normalised: lists of pairs as tuples) or raises
    :class:`Invalid`; ``expected`` says what it accepts ("an integer in [1, 100] steps")."""

    @property
    def expected(self) -> str: ...

    def __call__(self, value: Any) -> Any: ...


def _is_number(v: Any) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool)


@dataclass(frozen=True)
class Number:
    """A real number in a range (``lo``/``hi``, open ends with ``lo_open``/``hi_open``); ``finite``
    refuses inf (nan is always refused); ``cast`` returns a float; ``unit`` and ``note`` follow
    the range in the expected form ("a number in (0, 20] m")."""

    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    hi_open: bool = False
    finite: bool = True
    unit: str = ""
    note: str = ""
    cast: bool = False

    @property
    def expected(self) -> str:
        return f"a {'finite ' if self.finite and not _bounded(self) else ''}number{_range(self)}{self.note}"

    @property
    def bounds(self) -> str:
        """The range alone, as a help text gives it: "in (0, 60] frames per second", ">= 0 s"."""
        return _range(self).strip()

    def __call__(self, value: Any) -> Any:
        if not _is_number(value) or math.isnan(value) or (self.finite and math.isinf(value)):
            raise Invalid(self.expected, value)
        if not _inside(self, value):
            raise Invalid(self.expected, value)
        return float(value) if self.cast else value


@dataclass(frozen=True)
class Integer:
    """An integer in [``lo``, ``hi``] (bools refused); ``whole_floats`` accepts 4.0 as 4 (YAML,
    evenly spaced grids)."""

    lo: float = -math.inf
    hi: float = math.inf
    unit: str = ""
    note: str = ""
    whole_floats: bool = False
    lo_open: bool = dataclasses.field(default=False, init=False)
    hi_open: bool = dataclasses.field(default=False, init=False)

    @property
    def expected(self) -> str:
        return f"an integer{_range(self)}{self.note}"

    def __call__(self, value: Any) -> int:
        ok = isinstance(value, numbers.Integral) and not isinstance(value, bool)
        if not ok and self.whole_floats and _is_number(value) and math.isfinite(value) and value == int(value):
            value, ok = int(value), True
        if not ok or not _inside(self, value):
            raise Invalid(self.expected, value)
        return int(value)


def _bounded(r: Number | Integer) -> bool:
    return math.isfinite(r.lo) or math.isfinite(r.hi)


def _inside(r: Number | Integer, v: float) -> bool:
    above = v > r.lo if r.lo_open else v >= r.lo
    below = v < r.hi if r.hi_open else v <= r.hi
    return above and below


def _range(r: Number | Integer) -> str:
    lo, hi = math.isfinite(r.lo), math.isfinite(r.hi)
    if lo and hi:
        text = f" in {'(' if r.lo_open else '['}{r.lo:g}, {r.hi:g}{')' if r.hi_open else ']'}"
    elif lo:
        text = f" {'>' if r.lo_open else '>='} {r.lo:g}"
    elif hi:
        text = f" {'<' if r.hi_open else '<='} {r.hi:g}"
    else:
        return ""
    return text + r.unit


@dataclass(frozen=True)
class Flag:
    """true or false (not 0/1, not a string)."""

    expected: str = "true or false"

    def __call__(self, value: Any) -> bool:
        if not isinstance(value, bool):
            raise Invalid(self.expected, value)
        return value


class OneOf:
    """One of the given values (compared with ``==``, bools only to bools)."""

    def __init__(self, *options: Any) -> None:
        self.options = options

    def __repr__(self) -> str:
        return f"OneOf{self.options!r}"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, OneOf) and other.options == self.options

    def __hash__(self) -> int:
        return hash(self.options)

    @property
    def expected(self) -> str:
        return "one of " + ", ".join(repr(o) for o in self.options)

    def __call__(self, value: Any) -> Any:
        for o in self.options:
            if isinstance(o, bool) == isinstance(value, bool) and type(value) is not list and o == value:
                return value
        raise Invalid(self.expected, value)


@dataclass(frozen=True)
class Text:
    """A string: non-empty unless ``empty``; ``pattern`` a regular expression it must match whole,
    described by ``what``."""

    empty: bool = False
    pattern: str | None = None
    what: str = ""

    @property
    def expected(self) -> str:
        return self.what or ("a string" if self.empty else "a non-empty string")

    def __call__(self, value: Any) -> str:
        ok = isinstance(value, str) and (self.empty or bool(value))
        if not ok or (self.pattern is not None and not re.fullmatch(self.pattern, value)):
            raise Invalid(self.expected, value)
        return value


@dataclass(frozen=True)
class Pair:
    """Two finite numbers [x, y], returned as a tuple of floats."""

    expected: str = "two finite numbers [x, y]"

    def __call__(self, value: Any) -> tuple[float, float]:
        if isinstance(value, str | bytes | Mapping) or not hasattr(value, "__len__") or len(value) != 2:
            raise Invalid(self.expected, value)
        if not all(_is_number(v) for v in value) or not all(math.isfinite(v) for v in value):
            raise Invalid(self.expected, value)
        out = tuple(float(v) for v in value)
        return out  # type: ignore[return-value]


@dataclass(frozen=True)
class Seq:
    """A list (or tuple) of items, each checked by ``item``, returned as a ``kind`` (tuple);
    ``min_len``, ``max_len``, ``unique``, ``ascending`` (each item >= the one before); ``what``
    overrides the expected form."""

    item: Rule
    min_len: int = 0
    max_len: int | None = None
    unique: bool = False
    ascending: bool = False
    what: str = ""
    kind: type = tuple

    @property
    def expected(self) -> str:
        if self.what:
            return self.what
        size = "a non-empty list" if self.min_len >= 1 else "a list"
        return f"{size} of values, each {self.item.expected}"

    def __call__(self, value: Any) -> tuple[Any, ...]:
        if not isinstance(value, list | tuple):
            raise Invalid(self.expected, value)
        if len(value) < self.min_len or (self.max_len is not None and len(value) > self.max_len):
            raise Invalid(self.expected, value)
        out = []
        for i, v in enumerate(value):
            try:
                out.append(self.item(v))
            except Invalid as exc:
                if self.what:
                    raise Invalid(self.expected, value) from None
                raise Invalid(exc.expected, exc.value, f"[{i}]{exc.at}") from None
        if self.unique and len(set(out)) != len(out):
            raise Invalid(f"{self.expected}, no value twice", value)
        if self.ascending and any(b < a for a, b in itertools.pairwise(out)):
            raise Invalid(self.expected, value)
        return self.kind(out)


@dataclass(frozen=True)
class Maybe:
    """None or a value of ``rule``; ``none`` how None is written (a TOML key "left out", YAML's
    "null"), ``none_means`` what it stands for."""

    rule: Rule
    none_means: str = ""
    none: str = "left out"

    @property
    def expected(self) -> str:
        return f"{self.rule.expected} or {self.none}" + (f" ({self.none_means})" if self.none_means else "")

    def __call__(self, value: Any) -> Any:
        if value is None:
            return None
        try:
            return self.rule(value)
        except Invalid as exc:
            if exc.at:
                raise
            raise Invalid(self.expected, value) from None


class Either:
    """A value of the first of ``rules`` that takes it."""

    def __init__(self, *rules: Rule) -> None:
        self.rules = rules

    def __repr__(self) -> str:
        return f"Either{self.rules!r}"

    @property
    def expected(self) -> str:
        return " or ".join(r.expected for r in self.rules)

    def __call__(self, value: Any) -> Any:
        for r in self.rules:
            try:
                return r(value)
            except Invalid:
                continue
        raise Invalid(self.expected, value)


# -- places: where a key stands, as an error message names it ------------------------------------


class Place(Protocol):
    """Where a table stands in its input: ``key(k)`` names a key of it, ``table`` the table itself."""

    def key(self, k: str) -> str: ...

    @property
    def table(self) -> str: ...

    def sub(self, name: str) -> Place: ...


@dataclass(frozen=True)
class InFile:
    """A section of a TOML file: ``horizon in [control] of kerb-gap.toml``; ``section`` None: the
    top level (``duration in kerb-gap.toml``); ``label`` the section as written ("[control]",
    "[[pedestrian]] 'texter'")."""

    file: str
    label: str = ""

    def key(self, k: str) -> str:
        return f"{k} in {self.table}"

    @property
    def table(self) -> str:
        return f"{self.label} of {self.file}" if self.label else self.file

    def sub(self, name: str) -> InFile:
        """``[control]`` -> ``[control.gamma]``; ``pedestrian 'x'`` -> ``pedestrian 'x' [behaviour]``."""
        if not self.label:
            return InFile(self.file, f"[{name}]")
        if re.fullmatch(r"\[[\w.-]+\]", self.label):
            return InFile(self.file, f"[{self.label[1:-1]}.{name}]")
        return InFile(self.file, f"{self.label} [{name}]")


@dataclass(frozen=True)
class Dotted:
    """A field of a nested document by its dotted path, as YAML specs and Python objects name
    them: ``sweeps.si.params.horizon in spec.yaml`` (``file`` empty: ``sweeps.si.params.horizon``);
    ``path`` empty: the top level."""

    path: str = ""
    file: str = ""

    def key(self, k: str) -> str:
        name = f"{self.path}.{k}" if self.path else k
        return f"{name} in {self.file}" if self.file else name

    @property
    def table(self) -> str:
        if self.path:
            return f"{self.path} in {self.file}" if self.file else self.path
        return self.file or "the top level"

    def sub(self, name: str) -> Dotted:
        return Dotted(f"{self.path}.{name}" if self.path else name, self.file)


def did_you_mean(key: str, known: Iterable[str]) -> str:
    """ "did you mean 'horizon'?" for the nearest of ``known``; else the keys expected."""
    names = sorted(known)
    near = difflib.get_close_matches(key, names, n=1, cutoff=0.6)
    if near:
        return f"did you mean {near[0]!r}?"
    return "expected one of " + ", ".join(names) if names else "expected no keys"


def check_keys(
    table: Mapping[str, Any], known: Iterable[str], place: Place, what: str = "key", of: str = ""
) -> list[str]:
    """One line per key of ``table`` not in ``known``, each with the key meant (``what``: "key",
    "parameter"; ``of``: words after the key, " for family 'drive'")."""
    names = list(known)
    return [f"unknown {what} {k!r}{of} in {place.table}: {did_you_mean(str(k), names)}" for k in table
            if k not in names]  # fmt: skip


def bad(place: Place, k: str, exc: Invalid) -> str:
    """The line for a value refused by a rule: ``dt in [control] of x.toml must be a number > 0, got 0``."""
    return f"{place.key(k + exc.at)} must be {exc.expected}, got {shown(exc.value)}"


# -- dataclasses: rules in the annotations ---------------------------------------------------------

_PLAIN: dict[Any, Rule] = {
    float: Number(finite=False),
    int: Integer(),
    bool: Flag(),
    str: Text(empty=True),
}


def _rule_of(hint: Any) -> Rule | None:
    if get_origin(hint) is Annotated:
        for meta in hint.__metadata__:
            if callable(meta) and hasattr(meta, "expected"):
                return typing.cast(Rule, meta)
        return _rule_of(get_args(hint)[0])
    if hint in _PLAIN:
        return _PLAIN[hint]
    if get_origin(hint) in (Union, types.UnionType):
        args = [a for a in get_args(hint) if a is not type(None)]
        if len(args) == 1 and len(get_args(hint)) == 2:
            inner = _rule_of(args[0])
            return Maybe(inner) if inner is not None else None
    return None


@functools.cache
def rules_of(cls: type) -> Mapping[str, Rule]:
    """The rule of each field of dataclass ``cls`` that has one (from ``Annotated[..., rule]`` or
    a plain ``float``/``int``/``bool``/``str``/``X | None``); read once per class."""
    hints = typing.get_type_hints(cls, include_extras=True)
    rules = {f.name: _rule_of(hints.get(f.name)) for f in dataclasses.fields(cls)}
    return types.MappingProxyType({k: r for k, r in rules.items() if r is not None})


@functools.cache
def _sections(cls: type) -> Mapping[str, type]:
    """The fields of ``cls`` that hold a dataclass (also as ``X | None``): sections of a file."""
    out = {}
    for name, hint in typing.get_type_hints(cls).items():
        for t in (hint, *get_args(hint)):
            if isinstance(t, type) and dataclasses.is_dataclass(t):
                out[name] = t
    return types.MappingProxyType(out)


def check_fields(obj: Any, place: Place | None = None, error: type[SchemaError] = SchemaError) -> None:
    """Validate every field of dataclass ``obj`` that has a rule, setting the normalised values
    (frozen dataclasses too: call it first in ``__post_init__``); raises ``error`` with one line per
    field refused (``lane_width must be a number > 0, got -1``)."""
    where = place or Dotted()
    errors = []
    for name, rule in rules_of(type(obj)).items():
        try:
            value = rule(getattr(obj, name))
        except Invalid as exc:
            errors.append(bad(where, name, exc))
            continue
        object.__setattr__(obj, name, value)
    if errors:
        raise error(errors)


Converter = Callable[[Any, Place], Any]


def load(
    cls: type,
    table: Any,
    place: Place,
    *,
    convert: Mapping[str, Converter] | None = None,
    rename: Mapping[str, str] | None = None,
    error: type[SchemaError] = SchemaError,
) -> Any:
    """Build dataclass ``cls`` from ``table`` (a mapping of its fields' names), collecting one
    line per error: a key ``cls`` does not have (with the key meant), a required key missing, a
    value its rule refuses; a nested dataclass field is loaded from its sub-table in the same way.
    ``convert``: field -> function(value, place) for fields that need more than a rule (it raises
    :class:`SchemaError`); ``rename``: a key of the table -> the field it fills. The class's own
    ``__post_init__`` checks (between fields) follow, their message prefixed with the place."""
    if not isinstance(table, Mapping):
        raise error(f"{place.table} must be a table of keys, got {shown(table)}")
    rename = dict(rename or {})
    convert = dict(convert or {})
    fields = {f.name: f for f in dataclasses.fields(cls)}
    known = [k for k in fields if k not in rename.values()] + list(rename)
    errors = check_keys(table, known, place)
    rules = rules_of(cls)
    values: dict[str, Any] = {}
    for key, value in table.items():
        name = rename.get(key, key)
        if name not in fields or key not in known:
            continue
        try:
            if name in convert:
                values[name] = convert[name](value, place.sub(key))
            elif (sub := _sections(cls).get(name)) is not None and value is not None and not isinstance(value, sub):
                values[name] = load(sub, value, place.sub(key), error=error)
            elif name in rules:
                values[name] = rules[name](value)
            else:
                values[name] = value
        except Invalid as exc:
            errors.append(bad(place, key, exc))
        except SchemaError as exc:
            errors.extend(exc.errors)
    for name, f in fields.items():
        missing = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        key = next((k for k, v in rename.items() if v == name), name)
        if missing and name not in values and key not in table and name in convert:
            try:  # a converter says what it needs
                convert[name](None, place.sub(key))
            except (SchemaError, Invalid) as exc:
                errors.extend(exc.errors if isinstance(exc, SchemaError) else [bad(place, key, exc)])
                continue
        if missing and name not in values and key not in table:
            rule = rules.get(name)
            errors.append(f"missing key {key!r} in {place.table}" + (f": expected {rule.expected}" if rule else ""))
    if errors:
        raise error(errors)
    try:
        return cls(**values)
    except SchemaError as exc:  # check_fields of a value a converter passed on unchecked
        raise error([f"{place.table}: {e}" for e in exc.errors]) from None
    except (ValueError, TypeError) as exc:
        raise error(f"{place.table}: {' '.join(str(exc).split())}") from None


def load_each(
    cls: type, tables: Sequence[Any], places: Sequence[Place], *, convert: Mapping[str, Converter] | None = None
) -> tuple[Any, ...]:
    """:func:`load` of each of ``tables`` (a TOML array of tables) at its place, every table's errors
    collected and raised together."""
    out, errors = [], []
    for table, place in zip(tables, places, strict=True):
        try:
            out.append(load(cls, table, place, convert=convert))
        except SchemaError as exc:
            errors.extend(exc.errors)
    if errors:
        raise SchemaError(errors)
    return tuple(out)
