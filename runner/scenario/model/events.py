"""A program's events (`{run: 200us}`, `{lock: m}`, `{timer: {period: 1ms}}`) and the resources they share.

Each event says what it takes (a duration, a size, a resource, a thread) in its shorthand
or typed form; a `Resource` (mutex, condition, barrier, timer, ...) is declared once in
the scenario and named by the events of every thread that uses it.
"""

from __future__ import annotations

from typing import Any, Optional

from runner import units
from runner.errors import did_you_mean
from runner.scenario.model.base import DURATION_SCHEMA, MAX_MEM_EVENT, MAX_PERIOD, MIN_PERIOD, SIZE_SCHEMA, Duration, Size, Strict
from runner.scenario.model.vocabulary import PEER_WORDS, EventKind, Overrun, Pending, Protocol, ResourceKind, unknown_key
from runner.scenario.typed import Context, Field, KeyProblem

_EVENT_ALIASES = {"broad": "broadcast"}
_EVENT_EXAMPLES = {
    "duration": "{run: 200us}",
    "size": "{mem: 64KiB}",
    "resource": "{lock: name}",
    "wait": "{wait: {cond: name, mutex: name}}",
    "timer": "{timer: {period: 1ms}} or {timer: name}",
    "thread": "{spawn: worker}",
    "nothing": "yield",
}


_MAPPING_KEYS = {"timer": ["period", "overrun"], "wait": ["cond", "mutex"]}  # what an event's mapping value holds


def _event_shorthand(value: Any) -> Any:
    """`{run: 200us}`, `yield`, `{timer: {period: 1ms}}` as the typed form `{event: run, duration: 200us}`."""
    if isinstance(value, str):
        value = {value: None}
    if not isinstance(value, dict):
        raise ValueError(f"an event is a one-key mapping such as {{run: 200us}} or the word yield, got {type(value).__name__}")
    if "event" in value:
        return value
    if len(value) != 1:
        keys = ", ".join(repr(k) for k in value)
        raise ValueError(f"an event has exactly one key (its kind), got {len(value)}: {keys}; write each event as its own list item")
    ((word, arg),) = value.items()
    word = _EVENT_ALIASES.get(str(word), str(word))
    try:
        kind = EventKind(word)
    except ValueError:
        names = [k.value for k in EventKind]
        peer = PEER_WORDS["event"].get(word)
        hint = f"; {peer[1]}" if peer else did_you_mean(word, names)
        raise ValueError(f"unknown event {word!r}{hint or '; events: ' + ', '.join(names)}") from None
    takes = kind.takes
    if takes == "nothing":
        if arg not in (None, "", 0):
            raise ValueError(f"{word} takes no value; write it as the bare word `{word}`")
        return {"event": word}
    if arg is None:
        raise ValueError(f"{word} needs a value, e.g. {_EVENT_EXAMPLES[takes]}")
    if takes in _MAPPING_KEYS and isinstance(arg, dict):  # its keys said at their place, in this mapping's own words
        for key in arg:
            if key not in _MAPPING_KEYS[takes]:
                raise KeyProblem((word, key), unknown_key(key, takes, _MAPPING_KEYS[takes]))
    if takes == "wait":
        if not isinstance(arg, dict):
            raise ValueError(f"wait needs its condition and mutex, e.g. {_EVENT_EXAMPLES['wait']}")
        return {"event": word, **arg}
    named = takes in ("resource", "thread") or (takes == "timer" and not isinstance(arg, dict))
    if named and not isinstance(arg, str):  # the typed form's key (resource, thread) is not what the user wrote
        raise ValueError(f"{word} takes one name, e.g. {_EVENT_EXAMPLES[takes]}; got {type(arg).__name__} {arg!r}")
    if takes == "timer":
        return {"event": word, **arg} if isinstance(arg, dict) else {"event": word, "timer": arg}
    if takes == "thread":
        return {"event": word, "thread": arg}
    return {"event": word, takes: arg}


def _event_schema() -> dict[str, Any]:
    """How events are written (one-key mappings or a bare word), for editors; the typed form is internal."""
    name = {"type": "string", "description": "a name declared in resources"}
    timer = {
        "anyOf": [
            name,
            {
                "type": "object",
                "properties": {"period": DURATION_SCHEMA, "overrun": {"enum": [o.value for o in Overrun]}},
                "required": ["period"],
                "additionalProperties": False,
            },
        ]
    }
    wait = {"type": "object", "properties": {"cond": name, "mutex": name}, "required": ["cond", "mutex"], "additionalProperties": False}
    thread = {"type": "string", "description": "a thread of the same process declared with spawned: true"}
    by_takes = {"duration": DURATION_SCHEMA, "size": SIZE_SCHEMA, "resource": name, "timer": timer, "wait": wait, "thread": thread}
    words = [k.value for k in EventKind if k.takes == "nothing"]
    properties = {k.value: by_takes[k.takes] for k in EventKind if k.takes != "nothing"}
    properties.update({alias: properties[target] for alias, target in _EVENT_ALIASES.items()})
    return {
        "anyOf": [
            {"enum": words},
            {"type": "object", "properties": properties, "minProperties": 1, "maxProperties": 1, "additionalProperties": False},
        ],
        "description": "one event: {run: 200us}, {lock: name}, {timer: {period: 1ms}}, {wait: {cond: c, mutex: m}}, yield, ...",
        "examples": ["yield", {"run": "200us"}, {"lock": "data"}, {"timer": {"period": "1ms"}}],
    }


class Event(Strict):
    """One step of a program, written `{run: 200us}`, `{lock: name}`, `{timer: {period: 1ms}}` or `yield`."""

    event: EventKind
    duration: Optional[Duration] = None
    size: Optional[Size] = None
    resource: Optional[str] = None
    cond: Optional[str] = None
    mutex: Optional[str] = None
    timer: Optional[str] = Field(default=None, description="a named timer of resources")
    period: Optional[Duration] = None
    overrun: Optional[Overrun] = None
    thread: Optional[str] = Field(default=None, description="spawn: a thread of the same process declared with spawned: true")

    @classmethod
    def _schema(cls, schema: dict[str, Any]) -> None:
        """How events are written, not the typed form the model keeps."""
        schema.clear()
        schema.update(_event_schema())

    @classmethod
    def _before(cls, value: Any, context: Context) -> Any:
        return _event_shorthand(value)

    def _after(self, written: Any, context: Context) -> None:
        kind = self.event
        if kind is EventKind.WAIT and (self.cond is None or self.mutex is None):
            raise ValueError(f"wait needs both a cond and a mutex, e.g. {_EVENT_EXAMPLES['wait']}")
        if kind is EventKind.TIMER:
            if (self.timer is None) == (self.period is None):
                raise ValueError("a timer event names a timer of resources or has its own period, e.g. {timer: {period: 1ms}}")
            if self.period is not None and not MIN_PERIOD <= self.period <= MAX_PERIOD:
                raise ValueError(
                    f"timer period {units.format_duration(self.period)} is out of range; expected "
                    f"{units.format_duration(MIN_PERIOD)} to {units.format_duration(MAX_PERIOD)}"
                )
        elif self.overrun is not None or self.period is not None or self.timer is not None:
            raise ValueError("period, overrun and timer belong to timer events")
        if (kind is EventKind.SPAWN) != (self.thread is not None):
            raise ValueError(f"thread belongs to spawn events, and a spawn names its thread, e.g. {_EVENT_EXAMPLES['thread']}")
        if kind in (EventKind.RUN, EventKind.RUNTIME, EventKind.SLEEP) and self.duration is not None and self.duration > MAX_PERIOD:
            raise ValueError(
                f"{kind.value} {units.format_duration(self.duration)} is too long; at most {units.format_duration(MAX_PERIOD)}"
            )
        if kind in (EventKind.MEM, EventKind.IORUN) and self.size is not None and self.size > MAX_MEM_EVENT:
            raise ValueError(f"{kind.value} {units.format_size(self.size)} is too large; at most {units.format_size(MAX_MEM_EVENT)}")

    def _dumped(self, data: dict[str, Any]) -> Any:
        """The event as written: `{run: 200us}`, `yield`, `{wait: {cond: c, mutex: m}}` (what the spec hash covers)."""
        kind = self.event
        takes = kind.takes
        if takes == "nothing":
            return kind.value
        if takes == "wait":
            return {kind.value: {"cond": self.cond, "mutex": self.mutex}}
        if takes == "timer":
            if self.timer is not None:
                return {kind.value: self.timer}
            body: dict[str, Any] = {"period": units.format_duration(self.period or 0)}
            if self.overrun is not None:
                body["overrun"] = self.overrun.value
            return {kind.value: body}
        if takes == "duration":
            return {kind.value: units.format_duration(self.duration or 0)}
        if takes == "size":
            return {kind.value: units.format_size(self.size or 0)}
        if takes == "thread":
            return {kind.value: self.thread}
        return {kind.value: self.resource}

    def names(self) -> list[tuple[str, ResourceKind]]:
        """The resources this event names, with the kind each must be."""
        kind = self.event
        if kind is EventKind.WAIT:
            return [(self.cond or "", ResourceKind.COND), (self.mutex or "", ResourceKind.MUTEX)]
        if kind is EventKind.TIMER:
            return [(self.timer, ResourceKind.TIMER)] if self.timer is not None else []
        wanted = kind.resource_kind
        return [(self.resource or "", wanted)] if wanted is not None else []

    def label(self) -> str:
        """`lock data`, `run 200us`, `timer 1ms`, `wait ready (data)`: how the report names the event."""
        kind = self.event
        if kind is EventKind.WAIT:
            return f"wait {self.cond} ({self.mutex})"
        if kind is EventKind.TIMER:
            return f"timer {self.timer}" if self.timer else f"timer {units.format_duration(self.period or 0)}"
        if self.duration is not None:
            return f"{kind.value} {units.format_duration(self.duration)}"
        if self.size is not None:
            return f"{kind.value} {units.format_size(self.size)}"
        if self.thread is not None:
            return f"{kind.value} {self.thread}"
        return f"{kind.value} {self.resource}" if self.resource else kind.value


class Resource(Strict):
    """A synchronisation object or a named timer, declared once and shared by every thread that names it."""

    kind: ResourceKind
    protocol: Protocol = Field(default=Protocol.NONE, description="mutex: none, or inherit (priority inheritance)")
    period: Optional[Duration] = Field(default=None, description="timer: the period of its release grid")
    overrun: Overrun = Field(default=Overrun.SKIP, description="timer: skip, rebase or catchup on a late release")
    pending: Pending = Field(
        default=Pending.KEEP,
        description="queue: keep (a resume no thread waits for is kept for the next suspend, 32 at most; each wakes one "
        "thread) or drop (rt-app's resume: it wakes every thread suspended at that moment, and is lost, counted, when none is)",
    )

    def _after(self, written: Any, context: Context) -> None:
        if self.kind is ResourceKind.TIMER:
            if self.period is None:
                raise ValueError("a timer needs a period, e.g. {kind: timer, period: 10ms}")
            if not MIN_PERIOD <= self.period <= MAX_PERIOD:
                raise KeyProblem(
                    "period",
                    f"period {units.format_duration(self.period)} is out of range; expected "
                    f"{units.format_duration(MIN_PERIOD)} to {units.format_duration(MAX_PERIOD)}",
                )
        elif self.period is not None:
            raise KeyProblem("period", f"period is for timers, not a {self.kind.value}")
        if self.protocol is not Protocol.NONE and self.kind is not ResourceKind.MUTEX:
            raise KeyProblem("protocol", f"protocol is for mutexes, not a {self.kind.value}")
        if self.pending is not Pending.KEEP and self.kind is not ResourceKind.QUEUE:
            raise KeyProblem("pending", f"pending is for queues, not a {self.kind.value}")

    def _dumped(self, data: dict[str, Any]) -> Any:
        """Leave pending out while it is keep, so a cell's spec (and the hash stored baselines hold) reads as before it existed."""
        if self.pending is Pending.KEEP:
            data.pop("pending", None)
        return data
