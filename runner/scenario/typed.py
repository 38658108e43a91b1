"""Typed models checked against YAML data: frozen records, every problem at once, dumps and a JSON Schema.

A model is a frozen record made by keyword (a subclass of `Model`, typed as a dataclass) whose
fields say their type, default, bounds and words once (`Field`).  Three things follow from that
one declaration:
- `Model.parse(data)`: the data as written (YAML's dicts, lists and scalars) checked into a model,
  every problem collected with the key path it is at (`Invalid`), as `runner validate` prints them;
- `Model.dump()`: the model written back as JSON data (what a cell's spec hash covers);
- `json_schema(Model)`: the JSON Schema editors read.

Why not pydantic, which the scenario models used before: importing it and building the scenario's
validators took about 150 ms of `runner validate`'s 175 (its target is 100 ms for the whole
command), on every start, before a file was read.  This module is what the scenario stage needs
of it: strict scalars (no `"2"` read as 2, no `yes` read as true), unknown keys refused with a
"did you mean", unions chosen by a tag (`kind`), forms written in units (`100ms`) read before the
type and written back after it, and rules across fields checked once the fields are valid.

Hooks a model may define: `_before` (a shorthand written form into the mapping form), `_after`
(rules across fields, once every field is valid), `_dumped` (the written form of a dump) and
`_schema` (edits to the generated schema).  A rule that belongs at one key raises `KeyProblem`.
"""

from __future__ import annotations

import enum
import inspect
import re
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import MISSING
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal, NamedTuple, Optional, Union, get_args, get_origin

from runner.errors import closest, did_you_mean

if TYPE_CHECKING:
    from typing_extensions import Self, dataclass_transform
else:

    def dataclass_transform(**_: Any) -> Callable[[Any], Any]:
        return lambda cls: cls


Path = tuple[Union[str, int], ...]
Context = Optional[Mapping[str, Any]]
"""What checking may depend on beyond the data (the scenario's: the CPUs `count: cpus` resolves against)."""

_SCALARS = (str, int, float, bool)
_NONE_TYPE = type(None)
_CLASS_VAR = re.compile(r"\bClassVar\b")
_UNIONS = (Union, types.UnionType)


class KeyProblem(ValueError):
    """A problem a model's rule finds that belongs at one key of the object it checks.

    A rule spanning several fields (`priospread` with `count` and `sched`) can only be checked
    once they are all valid, on the whole object; raising this instead of a plain ValueError
    points the report at the key to change (its line), not at the object.
    """

    def __init__(self, key: str | tuple[str | int, ...], message: str) -> None:
        super().__init__(message)
        self.key = key

    @property
    def path(self) -> Path:
        """The key, or the path below the object (`("events", 2)`), the problem belongs at."""
        return self.key if isinstance(self.key, tuple) else (self.key,)


class Issue(NamedTuple):
    """One problem with checked data: where (the key path from the data checked), what, and whether at the key itself."""

    path: Path
    message: str
    key: bool = False  # an unknown key: point at the key, not at its value


class Invalid(ValueError):
    """Data that does not check: every issue found."""

    def __init__(self, issues: list[Issue]) -> None:
        super().__init__("; ".join(f"{'.'.join(map(str, i.path)) or '(top)'}: {i.message}" for i in issues))
        self.issues = issues


# ------------------------------------------------------------------ declarations
#
# Plain classes, not dataclasses: `runner validate` creates every model class on each start, and
# dataclasses.dataclass compiles each class's methods (about 0.7 ms a class on the 2-CPU VM: 20 ms
# for the scenario's models).  A model's methods here are shared, written once for all of them.


class Info(NamedTuple):
    """What a field declares beyond its type: its words, bounds and own checks (see `Field`)."""

    description: str = ""
    ge: Optional[float] = None
    le: Optional[float] = None
    min_items: Optional[int] = None
    before: Optional[Callable[[Any], Any]] = None
    check: Optional[Callable[[Any], Any]] = None
    schema: Optional[dict[str, Any]] = None


class _Declared(NamedTuple):
    """A field as its class declares it: `Field(...)`'s answer, until the class is made."""

    default: Any
    factory: Any
    info: Info


class Slot(NamedTuple):
    """One field of a model class: its name, its default or default factory (else MISSING), its declaration."""

    name: str
    default: Any
    factory: Any
    info: Info

    @property
    def required(self) -> bool:
        return self.default is MISSING and self.factory is MISSING


def Field(
    *,
    default: Any = MISSING,
    default_factory: Any = MISSING,
    description: str = "",
    ge: Optional[float] = None,
    le: Optional[float] = None,
    min_items: Optional[int] = None,
    before: Optional[Callable[[Any], Any]] = None,
    check: Optional[Callable[[Any], Any]] = None,
    schema: Optional[dict[str, Any]] = None,
) -> Any:
    """A model field: its default (or factory), its words for the schema, and what checking it adds to its type.

    `ge`/`le` bound a number, `min_items` a list; `before` reads the value as written before the type
    is checked, `check` judges the value once its type is (raise ValueError; return the value to keep);
    `schema` is merged into the field's generated JSON Schema.
    """
    return _Declared(default, default_factory, Info(description, ge, le, min_items, before, check, schema))


class Written:
    """`Annotated` metadata of a type written in a form of its own (`100ms` for an int of nanoseconds).

    `parse(value, context)` reads the written form into the base type (raise ValueError),
    `dump(value)` writes it back, `schema` is its JSON Schema (in place of the base type's).
    Hashed by identity, as typing hashes `Annotated` metadata and a schema is a dict.
    """

    __slots__ = ("dump", "parse", "schema")

    def __init__(
        self,
        parse: Optional[Callable[[Any, Context], Any]] = None,
        dump: Optional[Callable[[Any], Any]] = None,
        schema: Optional[dict[str, Any]] = None,
    ) -> None:
        self.parse, self.dump, self.schema = parse, dump, schema


class Tagged:
    """`Annotated` metadata of a union of models: which member a mapping is.

    By `key`, the member whose field of that name has the mapping's value as its default
    (`kind: periodic`); or by `choose`, a function of the value naming the member class (a
    module-level function: annotations are evaluated in the class's namespace, where a lambda
    would not find the module's names when called).
    """

    __slots__ = ("choose", "key")

    def __init__(self, key: str = "", choose: Optional[Callable[[Any], type]] = None) -> None:
        self.key, self.choose = key, choose


class Schema:
    """`Annotated` metadata adding keywords to a type's JSON Schema (`{"minItems": 1}`)."""

    __slots__ = ("extra",)

    def __init__(self, extra: dict[str, Any]) -> None:
        self.extra = extra


class FrozenError(AttributeError):
    """A model's fields are set once, when it is made."""


@dataclass_transform(kw_only_default=True, frozen_default=True, eq_default=True, field_specifiers=(Field,))
class Model:
    """Base of the typed models: each subclass is a frozen record of the fields it annotates, made by keyword.

    Unknown keys are refused; fields are strict (an integer is not a string, a boolean not a number).
    Models compare and hash by type and fields, and print as `Name(field=value, ...)`.
    """

    _slots: ClassVar[tuple[Slot, ...]] = ()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        slots = {slot.name: slot for slot in cls._slots}
        own = inspect.get_annotations(cls)
        for name, slot in list(slots.items()):  # a default given anew without its annotation is still that field's
            if name in cls.__dict__ and name not in own:
                given = cls.__dict__[name]
                declared = given if isinstance(given, _Declared) else _Declared(given, MISSING, slot.info)
                slots[name] = Slot(name, declared.default, declared.factory, declared.info)
                delattr(cls, name)
        for name, annotation in own.items():
            if name.startswith("_") or _CLASS_VAR.search(str(annotation)):
                continue  # a class's own state, set by its hooks: not a key of the data
            given = cls.__dict__.get(name, MISSING)
            declared = given if isinstance(given, _Declared) else _Declared(given, MISSING, Info())
            slots[name] = Slot(name, declared.default, declared.factory, declared.info)
            if isinstance(given, _Declared):
                delattr(cls, name)  # an instance always holds its own value
        cls._slots = tuple(slots.values())

    def __init__(self, **values: Any) -> None:
        for slot in self._slots:
            if slot.name in values:
                value = values.pop(slot.name)
            elif slot.default is not MISSING:
                value = slot.default
            elif slot.factory is not MISSING:
                value = slot.factory()
            else:
                raise TypeError(f"{type(self).__name__}() needs the keyword argument {slot.name!r}")
            object.__setattr__(self, slot.name, value)
        if values:
            raise TypeError(f"{type(self).__name__}() has no field {', '.join(map(repr, values))}")

    def __setattr__(self, name: str, value: Any) -> None:
        raise FrozenError(f"{type(self).__name__} is frozen: cannot set {name!r}")

    def __delattr__(self, name: str) -> None:
        raise FrozenError(f"{type(self).__name__} is frozen: cannot delete {name!r}")

    def _values(self) -> tuple[Any, ...]:
        return tuple(getattr(self, slot.name) for slot in self._slots)

    def __eq__(self, other: object) -> bool:
        """The same type with the same fields and the same state its hooks set (`ThreadSpec`'s per-CPU count)."""
        return isinstance(other, Model) and type(other) is type(self) and self.__dict__ == other.__dict__

    def __hash__(self) -> int:
        return hash((type(self), self._values()))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({', '.join(f'{slot.name}={getattr(self, slot.name)!r}' for slot in self._slots)})"

    @classmethod
    def _before(cls, value: Any, context: Context) -> Any:
        """The mapping form of a value written in a shorthand (`fifo:80`); raise ValueError or KeyProblem."""
        return value

    @classmethod
    def _peer_word(cls, key: str) -> Optional[tuple[Optional[str], str]]:
        """What an unknown key that another tool's vocabulary uses means here (rt-app's `instance`: `count`): the field
        it stands for (None: none of this model) and the words that say so; None when it is no such word."""
        return None

    def _after(self, written: Any, context: Context) -> None:
        """Rules across fields, once every field is valid (`written`: the data as given); raise ValueError or KeyProblem.

        A value the rules resolve (a default that depends on others) is set with object.__setattr__."""

    def _dumped(self, data: dict[str, Any]) -> Any:
        """The dump as written: keys left out while unused, or a shorter form."""
        return data

    @classmethod
    def _schema(cls, schema: dict[str, Any]) -> None:
        """Edit this model's generated JSON Schema in place (examples, a written form)."""

    @classmethod
    def parse(cls, data: Any, context: Context = None) -> Self:
        """`data` checked into this model; raise Invalid with every issue."""
        return parse(cls, data, context)

    def dump(self, exclude: frozenset[str] = frozenset()) -> Any:
        """This model as JSON data, its fields but `exclude` (top level only)."""
        return _dump_model(self, exclude)

    def replace(self, **changes: Any) -> Self:
        """A copy with `changes` (not checked again), keeping the state its hooks set."""
        copy = type(self)(**{**{slot.name: getattr(self, slot.name) for slot in self._slots}, **changes})
        names = {slot.name for slot in self._slots}
        for name, value in self.__dict__.items():
            if name not in names:
                object.__setattr__(copy, name, value)
        return copy


# ----------------------------------------------------------------------- checking

_INVALID: Any = object()
_Checker = Callable[[Any, Path, "_Run"], Any]


class _Run:
    """One call of `parse`: its context and the issues found so far."""

    __slots__ = ("context", "issues")

    def __init__(self, context: Context, issues: list[Issue]) -> None:
        self.context, self.issues = context, issues

    def add(self, path: Path, message: str, key: bool = False) -> Any:
        self.issues.append(Issue(path, message, key))
        return _INVALID

    def raised(self, path: Path, exc: ValueError, value: Any) -> Any:
        """An issue from a hook's ValueError; a KeyProblem goes to its key, as far as `value` has it."""
        if isinstance(exc, KeyProblem):
            path = path + _existing(value, exc.path)
        return self.add(path, str(exc))


def parse(tp: Any, data: Any, context: Context = None) -> Any:
    """`data` checked into type `tp` (a model, a list of them, a union...); raise Invalid with every issue."""
    run = _Run(context, [])
    value = _checker(tp)(data, (), run)
    if run.issues or value is _INVALID:
        raise Invalid(run.issues or [Issue((), "invalid")])
    return value


def _existing(value: Any, path: Path) -> Path:
    """The longest start of `path` that exists in `value`: where a KeyProblem can point."""
    out: list[str | int] = []
    for elem in path:
        if (isinstance(value, dict) and elem in value) or (isinstance(value, list) and isinstance(elem, int) and 0 <= elem < len(value)):
            value = typing.cast(Any, value)[elem]  # a key of this dict or an index of this list, as just checked
        else:
            break
        out.append(elem)
    return tuple(out)


def _got(value: Any) -> str:
    """`, got 'x'` for a scalar as written; nothing for a mapping or a list, which would be long, or for an empty value."""
    return f", got {value!r}" if isinstance(value, _SCALARS) else ""


def _mismatch(run: _Run, path: Path, what: str, value: Any) -> Any:
    message = f"input should be {what}{_got(value)}"
    if what == "a valid string" and isinstance(value, bool):  # YAML 1.1 reads yes/no/on/off as booleans
        message += "; YAML reads an unquoted yes, no, on, off, true or false as a boolean: quote it ('off') to keep the word"
    elif what == "a valid boolean":
        message += "; expected true or false (or on/off, yes/no), unquoted"
    return run.add(path, message)


_CHECKERS: dict[tuple[Any, str], _Checker] = {}


def _checker(tp: Any) -> _Checker:
    """The checker of type `tp`, built once (by its repr as well: typing finds Union[str, int] equal to Union[int, str],
    but a union's checker tries its members in their order)."""
    key = (tp, repr(tp))
    found = _CHECKERS.get(key)
    if found is None:
        found = _CHECKERS[key] = _build(tp)
    return found


def _build(tp: Any) -> _Checker:
    origin = get_origin(tp)
    if origin is Annotated:
        return _annotated(tp)
    if isinstance(tp, type) and issubclass(tp, Model):
        return _model_checker(tp)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return _enum_checker(tp)
    if origin is Literal:
        return _literal_checker(get_args(tp))
    if origin in _UNIONS:
        return _union_checker(get_args(tp))
    if origin in (list, tuple):
        return _list_checker(get_args(tp)[0], as_tuple=origin is tuple)
    if origin is dict:
        return _dict_checker(get_args(tp)[1])
    scalar = _SCALAR_CHECKERS.get(tp)
    if scalar is not None:
        return scalar
    if tp is Any:
        return lambda value, path, run: value
    raise TypeError(f"runner.scenario.typed cannot check {tp!r}")


def _int(value: Any, path: Path, run: _Run) -> Any:
    return value if isinstance(value, int) and not isinstance(value, bool) else _mismatch(run, path, "a valid integer", value)


def _bool(value: Any, path: Path, run: _Run) -> Any:
    return value if isinstance(value, bool) else _mismatch(run, path, "a valid boolean", value)


def _str(value: Any, path: Path, run: _Run) -> Any:
    return value if isinstance(value, str) else _mismatch(run, path, "a valid string", value)


def _float(value: Any, path: Path, run: _Run) -> Any:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        try:
            return float(value)
        except OverflowError:
            return run.add(path, f"input should be a valid number; got an integer of about {len(str(abs(value)))} digits")
    return _mismatch(run, path, "a valid number", value)


def _none(value: Any, path: Path, run: _Run) -> Any:
    return None if value is None else _mismatch(run, path, "null", value)


_SCALAR_CHECKERS: dict[Any, _Checker] = {int: _int, bool: _bool, str: _str, float: _float, _NONE_TYPE: _none}


def _annotated(tp: Any) -> _Checker:
    written = next((m for m in tp.__metadata__ if isinstance(m, Written)), None)
    tagged = next((m for m in tp.__metadata__ if isinstance(m, Tagged)), None)
    base = _tagged_checker(tp.__origin__, tagged) if tagged is not None else _checker(tp.__origin__)
    if written is None or written.parse is None:
        return base
    parse_form = written.parse

    def check(value: Any, path: Path, run: _Run) -> Any:
        try:
            value = parse_form(value, run.context)
        except ValueError as exc:
            return run.raised(path, exc, value)
        return base(value, path, run)

    return check


def _enum_checker(tp: type[enum.Enum]) -> _Checker:
    values = {member.value: member for member in tp}
    words = [str(v) for v in values]

    def check(value: Any, path: Path, run: _Run) -> Any:
        if isinstance(value, tp):
            return value
        try:
            return values[value]
        except (KeyError, TypeError):
            return run.add(path, f"{value!r} is not valid{did_you_mean(str(value), words)}; expected one of: {', '.join(words)}")

    return check


def _literal_checker(allowed: tuple[Any, ...]) -> _Checker:
    def check(value: Any, path: Path, run: _Run) -> Any:
        if any(type(value) is type(a) and value == a for a in allowed):  # strict: 1.0 is not 1, True is not 1
            return value
        return _mismatch(run, path, " or ".join(repr(a) for a in allowed), value)

    return check


def _union_checker(members: tuple[Any, ...]) -> _Checker:
    """An untagged union: the member whose type the value has exactly, else the first that checks."""
    if _NONE_TYPE in members:
        rest = tuple(m for m in members if m is not _NONE_TYPE)
        inner = _checker(rest[0] if len(rest) == 1 else Union[rest])
        return lambda value, path, run: None if value is None else inner(value, path, run)
    checkers = [_checker(m) for m in members]
    exact = tuple(m for m in members if m in _SCALAR_CHECKERS)
    names = _union_words(members)
    lists = [c for m, c in zip(members, checkers) if get_origin(m.__origin__ if get_origin(m) is Annotated else m) in (list, tuple)]

    def check(value: Any, path: Path, run: _Run) -> Any:
        if type(value) in exact:
            return value
        if isinstance(value, (list, tuple)) and len(lists) == 1:
            return lists[0](value, path, run)  # the one member a list can be: its own problems, at its items
        for one in checkers:
            scratch = _Run(run.context, [])
            out = one(value, path, scratch)
            if not scratch.issues and out is not _INVALID:
                return out
        return run.add(path, f"input should be {names}{_got(value)}")

    return check


_WORDS = {str: "text", int: "a number", float: "a number", bool: "a boolean"}


def _union_words(members: tuple[Any, ...]) -> str:
    """What a union takes, in words: `text, a number, a boolean or a list of them`."""
    words: list[str] = []
    scalars = {m for m in members if m in _WORDS}
    for member in members:
        if get_origin(member) is Annotated:
            member = member.__origin__
        if member in _WORDS:
            word = _WORDS[member]
        elif get_origin(member) is list:
            items = get_args(member)[0]
            inner = set(get_args(items)) if get_origin(items) in _UNIONS else {items}
            word = "a list of them" if inner <= scalars else f"a list of {_union_words(tuple(inner))}"
        else:
            word = getattr(member, "__name__", str(member))
        if word not in words:
            words.append(word)
    return ", ".join(words[:-1]) + " or " + words[-1] if len(words) > 1 else words[0]


def _list_checker(item_type: Any, as_tuple: bool) -> _Checker:
    """list[X], or tuple[X, ...] (a list as written, made a tuple)."""
    item = _checker(item_type)

    def check(value: Any, path: Path, run: _Run) -> Any:
        if not isinstance(value, (list, tuple)):
            return _mismatch(run, path, "a valid list", value)
        out = [item(v, path + (i,), run) for i, v in enumerate(value)]
        if any(v is _INVALID for v in out):
            return _INVALID
        return tuple(out) if as_tuple else out

    return check


def _dict_checker(value_type: Any) -> _Checker:
    item = _checker(value_type)

    def check(value: Any, path: Path, run: _Run) -> Any:
        if not isinstance(value, dict):
            return _mismatch(run, path, "a mapping (key: value)", value)
        out = {}
        for key, v in value.items():
            if not isinstance(key, str):
                run.add(path + (key,), f"the key {key!r} should be text", key=True)
                out[key] = _INVALID
                continue
            out[key] = item(v, path + (key,), run)
        return _INVALID if any(v is _INVALID for v in out.values()) else out

    return check


def _tagged_checker(union: Any, tagged: Tagged) -> _Checker:
    """A union of models chosen by a tag (`kind: periodic`) or by a function of the value."""
    members = [m for m in get_args(union) if m is not _NONE_TYPE]
    models = [get_args(m)[0] if get_origin(m) is Annotated else m for m in members]
    by_tag: dict[str, type[Model]] = {}
    if tagged.key:
        for model in models:
            default = next(slot.default for slot in model._slots if slot.name == tagged.key)
            by_tag[str(default)] = model
    tags = list(by_tag)
    optional = _NONE_TYPE in get_args(union)

    def check(value: Any, path: Path, run: _Run) -> Any:
        if value is None and optional:
            return None
        if isinstance(value, tuple(models)):
            return value
        if tagged.choose is not None:
            return _checker(tagged.choose(value))(value, path, run)
        if not isinstance(value, dict):
            return _mismatch(run, path, f"a mapping with a {tagged.key!r} key (one of: {', '.join(tags)})", value)
        if tagged.key not in value:
            return run.add(path, f"missing {tagged.key!r}; expected one of: {', '.join(tags)}")
        tag = value[tagged.key]
        model = by_tag.get(tag) if isinstance(tag, str) else None
        if model is None:
            hint = did_you_mean(str(tag), tags)
            return run.add(path + (tagged.key,), f"unknown {tagged.key} {str(tag)!r}{hint}; expected one of: {', '.join(tags)}")
        return _checker(model)(value, path, run)

    return check


class _FieldPlan(NamedTuple):
    """How one field of a model is checked, dumped and described."""

    name: str
    type: Any
    info: Info
    required: bool
    default: Any  # MISSING, or the default value when it is one (not made by a factory)
    check: _Checker
    dump: Callable[[Any], Any]


_PLANS: dict[type, tuple[_FieldPlan, ...]] = {}


def fields_of(model: type[Model]) -> tuple[_FieldPlan, ...]:
    """The fields of `model`, in declared order, with their types resolved: built on first use, as types may refer ahead."""
    found = _PLANS.get(model)
    if found is None:
        hints = typing.get_type_hints(model, include_extras=True)
        plans = [
            _FieldPlan(s.name, hints[s.name], s.info, s.required, s.default, _field_checker(hints[s.name], s.info), _dumper(hints[s.name]))
            for s in model._slots
        ]
        found = _PLANS[model] = tuple(plans)
    return found


def _field_checker(tp: Any, info: Info) -> _Checker:
    check_type = _checker(tp)
    if info.before is None and info.check is None and info.ge is None and info.le is None and info.min_items is None:
        return check_type
    before, after, ge, le, min_items = info.before, info.check, info.ge, info.le, info.min_items

    def check(value: Any, path: Path, run: _Run) -> Any:
        if before is not None:
            try:
                value = before(value)
            except ValueError as exc:
                return run.raised(path, exc, value)
        value = check_type(value, path, run)
        if value is _INVALID or value is None:
            return value
        if ge is not None and not value >= ge:  # NaN meets no bound
            return run.add(path, f"input should be greater than or equal to {_bound(ge)}{_got(value)}")
        if le is not None and not value <= le:
            return run.add(path, f"input should be less than or equal to {_bound(le)}{_got(value)}")
        if min_items is not None and len(value) < min_items:
            return run.add(path, f"list should have at least {min_items} item{'s' if min_items != 1 else ''}, not {len(value)}")
        if after is not None:
            try:
                value = after(value)
            except ValueError as exc:
                return run.raised(path, exc, value)
        return value

    return check


def _bound(limit: float) -> str:
    """A bound as written: `1099511627776`, not `1.09951e+12`."""
    return str(int(limit)) if float(limit).is_integer() else str(limit)


def _model_checker(model: type[Model]) -> _Checker:
    def check(value: Any, path: Path, run: _Run) -> Any:
        if isinstance(value, model):
            return value
        plans = fields_of(model)
        written = value
        try:
            value = model._before(value, run.context)
        except ValueError as exc:
            return run.raised(path, exc, value)
        if isinstance(value, model):
            return value
        if not isinstance(value, dict):
            return _mismatch(run, path, "a mapping (key: value)", value)
        names = [p.name for p in plans]
        unknown = [k for k in value if k not in names]
        missing = [p.name for p in plans if p.required and p.name not in value]
        for key in unknown:
            peer = model._peer_word(str(key))  # a word of rt-app's or cyclictest's: what it is here, before any typo
            if peer is not None:
                meant, hint = peer[0], f"; {peer[1]}"
            else:
                meant = closest(str(key), names)
                hint = f"; did you mean {meant!r}?" if meant is not None else f"; expected one of: {', '.join(names)}"
            if meant is not None and meant in missing:
                missing.remove(meant)  # `polcy:` for `policy:` is one mistake: the unknown key's "did you mean" says both
            run.add(path + (key,), f"unknown key {key!r}{hint}", key=True)
        for name in missing:
            run.add(path + (name,), f"missing required key {name!r}")
        given: dict[str, Any] = {}
        for plan in plans:
            if plan.name in value:
                given[plan.name] = plan.check(value[plan.name], path + (plan.name,), run)
        if unknown or missing or any(v is _INVALID for v in given.values()):
            return _INVALID
        obj = model(**given)
        try:
            obj._after(written, run.context)
        except ValueError as exc:
            return run.raised(path, exc, written)  # at a key as far as the file writes it (not `phases` of `events:`)
        return obj

    return check


# ------------------------------------------------------------------------ dumping


def _dump_model(obj: Model, exclude: frozenset[str] = frozenset()) -> Any:
    data = {p.name: p.dump(getattr(obj, p.name)) for p in fields_of(type(obj)) if p.name not in exclude}
    return obj._dumped(data)


def _dump_any(value: Any) -> Any:
    """JSON data of a value of no declared form: a model by its own fields, containers item by item."""
    if isinstance(value, Model):
        return _dump_model(value)
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, (list, tuple)):
        return [_dump_any(v) for v in value]
    if isinstance(value, dict):
        return {k: _dump_any(v) for k, v in value.items()}
    return value


def _dumper(tp: Any) -> Callable[[Any], Any]:
    """How a value of declared type `tp` is written as JSON data: its written form where it has one."""
    origin = get_origin(tp)
    if origin is Annotated:
        written = next((m for m in tp.__metadata__ if isinstance(m, Written) and m.dump is not None), None)
        if written is not None and written.dump is not None:
            form = written.dump
            return lambda value: None if value is None else form(value)
        return _dumper(tp.__origin__)
    if origin in _UNIONS:
        members = [m for m in get_args(tp) if m is not _NONE_TYPE]
        if len(members) == 1:
            inner = _dumper(members[0])
            return lambda value: None if value is None else inner(value)
        return _dump_any
    if origin in (list, tuple):
        item = _dumper(get_args(tp)[0])
        return lambda value: [item(v) for v in value]
    if origin is dict:
        item = _dumper(get_args(tp)[1])
        return lambda value: {k: item(v) for k, v in value.items()}
    if tp is float:
        return float
    return _dump_any


# ------------------------------------------------------------------------- schema


def text_schema(pattern: str, expected: str, **extra: Any) -> dict[str, Any]:
    """The schema of text matching `pattern`, with the words an editor shows for text that does not match.

    `expected` is what `runner validate` says is expected of the value (`units.DURATION_EXPECTED`...): the
    same words, from the same declaration, where yaml-language-server would otherwise print the whole pattern
    (`patternErrorMessage` is its keyword and VS Code's, beside JSON Schema's; validators take it as an annotation).
    """
    return {"type": "string", "pattern": pattern, "patternErrorMessage": f"expected {expected}", **extra}


def json_schema(root: type[Model]) -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of `root`: its properties at the top, every other model and enum in `$defs`."""
    defs: dict[str, Any] = {}
    top = _model_schema(root, defs)
    used = _reachable(top, defs, set())  # a model's own schema hook may have replaced what referred to one (Event's kind)
    return {**top, "$defs": {name: defs[name] for name in sorted(used)}} if used else top


def _model_schema(model: type[Model], defs: dict[str, Any]) -> dict[str, Any]:
    properties = {}
    for plan in fields_of(model):
        prop = _type_schema(plan.type, defs)
        info = plan.info
        bounds = {"minimum": info.ge, "maximum": info.le, "minItems": info.min_items}
        target = prop["anyOf"][0] if _nullable(plan.type) and "anyOf" in prop else prop
        for key, bound in bounds.items():
            if bound is not None:
                target[key] = int(bound) if float(bound).is_integer() else bound
        if plan.default is not MISSING:
            prop["default"] = plan.dump(plan.default)
        if info.description:
            prop["description"] = info.description
        if not _names_a_definition(plan.type):
            prop.setdefault("title", plan.name.replace("_", " ").title())
        if info.schema:
            prop.update(info.schema)
        properties[plan.name] = dict(sorted(prop.items()))
    schema: dict[str, Any] = {
        "additionalProperties": False,
        "description": inspect.cleandoc(model.__doc__ or ""),
        "properties": properties,
        "title": model.__name__,
        "type": "object",
    }
    required = [p.name for p in fields_of(model) if p.required]
    if required:
        schema["required"] = required
    model._schema(schema)
    return schema


def _names_a_definition(tp: Any) -> bool:
    """Whether a field's type is a model or an enum (bare or optional), which its definition in `$defs` titles."""
    if get_origin(tp) is Annotated:
        return _names_a_definition(tp.__origin__)
    if get_origin(tp) in _UNIONS:
        members = [m for m in get_args(tp) if m is not _NONE_TYPE]
        return len(members) == 1 and _names_a_definition(members[0])
    return isinstance(tp, type) and issubclass(tp, (Model, enum.Enum))


def _reachable(schema: Any, defs: dict[str, Any], seen: set[str]) -> set[str]:
    """The names of `defs` that `schema` refers to, directly or through other definitions."""
    if isinstance(schema, dict):
        ref = schema.get("$ref")
        if isinstance(ref, str) and ref.startswith("#/$defs/") and ref[8:] not in seen:
            seen.add(ref[8:])
            _reachable(defs.get(ref[8:]), defs, seen)
        for value in schema.values():
            _reachable(value, defs, seen)
    elif isinstance(schema, list):
        for value in schema:
            _reachable(value, defs, seen)
    return seen


def _nullable(tp: Any) -> bool:
    if get_origin(tp) is Annotated:
        return _nullable(tp.__origin__)
    return get_origin(tp) in _UNIONS and _NONE_TYPE in get_args(tp)


def _ref(name: str) -> dict[str, Any]:
    return {"$ref": f"#/$defs/{name}"}


def _type_schema(tp: Any, defs: dict[str, Any]) -> dict[str, Any]:
    origin = get_origin(tp)
    if origin is Annotated:
        written = next((m for m in tp.__metadata__ if isinstance(m, Written) and m.schema is not None), None)
        out = dict(written.schema) if written is not None and written.schema is not None else _type_schema(tp.__origin__, defs)
        for extra in (m for m in tp.__metadata__ if isinstance(m, Schema)):
            out.update(extra.extra)
        return out
    if isinstance(tp, type) and issubclass(tp, Model):
        if tp.__name__ not in defs:
            defs[tp.__name__] = {}  # a placeholder first: a model may refer to itself
            defs[tp.__name__] = _model_schema(tp, defs)
        return _ref(tp.__name__)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        if tp.__name__ not in defs:
            entry: dict[str, Any] = {"enum": [m.value for m in tp], "title": tp.__name__, "type": "string"}
            if tp.__doc__ and tp.__doc__ != enum.Enum.__doc__ and "An enumeration." not in tp.__doc__:
                entry["description"] = inspect.cleandoc(tp.__doc__)
            defs[tp.__name__] = entry
        return _ref(tp.__name__)
    if origin is Literal:
        values = get_args(tp)
        return {"const": values[0], "type": "string"} if len(values) == 1 else {"enum": list(values)}
    if origin in _UNIONS:
        members = get_args(tp)
        rest = [m for m in members if m is not _NONE_TYPE]
        if _NONE_TYPE in members:
            inner = _type_schema(rest[0] if len(rest) == 1 else Union[tuple(rest)], defs)
            return {"anyOf": [inner, {"type": "null"}]}
        if all(isinstance(m, type) and issubclass(m, Model) for m in (get_args(x)[0] if get_origin(x) is Annotated else x for x in rest)):
            return {"oneOf": [_type_schema(m, defs) for m in rest]}
        return {"anyOf": [_type_schema(m, defs) for m in rest]}
    if origin in (list, tuple):
        return {"items": _type_schema(get_args(tp)[0], defs), "type": "array"}
    if origin is dict:
        return {"additionalProperties": _type_schema(get_args(tp)[1], defs), "type": "object"}
    simple = {int: {"type": "integer"}, bool: {"type": "boolean"}, str: {"type": "string"}, float: {"type": "number"}, Any: {}}
    if tp in simple:
        return dict(simple[tp])
    raise TypeError(f"runner.scenario.typed has no schema for {tp!r}")
