"""Converting the parts of an rt-app task: its events, scheduling and CPUs, names, and the resources its events use.

`Reader` holds one conversion's state, says problems and notes at their place in the file
(`At`) and reads rt-app's values with their types; `Parts` builds on it what a task is
made of.  The task and file level (`runner.scenario.rtapptasks`) builds on `Parts`.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from typing import Any, Optional, Union

from runner import units
from runner.errors import Problem
from runner.scenario.model import COMM_MAX, control_character
from runner.scenario.rtappjson import Relaxed, first_comment, locate_steps
from runner.scenario.rtappwords import MAX_INT, MAX_US, NEWER_EVENTS, NICE_POLICIES, POLICIES, RT_POLICIES, SCHED_KEYS, Pairs, event_kind
from runner.scenario.yamlsource import Path, dotted, printable

# ------------------------------------------------------------------------- conversion


@dataclass(frozen=True)
class At:
    """Where a value is: its key path as shown to users, and its pair/item indexes in the file."""

    names: tuple[Union[str, int], ...] = ()
    steps: tuple[int, ...] = ()

    def key(self, index: int, name: str) -> At:
        return At(self.names + (name,), self.steps + (index,))

    def item(self, index: int) -> At:
        return At(self.names + (index,), self.steps + (index,))

    def __str__(self) -> str:
        return dotted(self.names)


class Located(dict[str, Any]):
    """A mapping of the scenario (a thread, its work, a phase, an event, a resource) and where in the rt-app file it came from."""

    def __init__(self, items: dict[str, Any], at: At):
        super().__init__(items)
        self.at = at


@dataclass(frozen=True)
class _Ref:
    """A named resource an event uses; its final name is decided once every use is known."""

    kind: str  # mutex, cond, barrier, queue, timer
    name: str


@dataclass(frozen=True)
class _PrivateTimer:
    """A `unique` timer: a private timer whose overrun depends on every event naming it in the thread."""

    task: int
    ref: str
    period_us: int


@dataclass(frozen=True)
class _Fork:
    """A fork event until every task is read: the task it names, its spawn event, where it was."""

    conv: Any
    target: str
    spawn: dict[str, Any]
    at: Any


@dataclass
class _Wake:
    """A suspend or resume until every task is read.

    rt-app's suspend and resume of X take the condition and the mutex X (lock, wait or
    broadcast, unlock): a resume with no thread suspended at that moment is lost.  Where a
    wait, sync, signal or lock also names X, that sharing is what the workload relies on, so
    they take them here too.  Otherwise they take the queue X with `pending: drop`, which
    behaves as that condition does (a resume wakes every thread suspended then, and is lost
    when none is) and measures what a queue does: the wake-up latency of each resume, and the
    activations of a thread that suspends without a timer.
    """

    kind: str  # suspend or resume
    name: str
    at: Any
    task: int
    shared: bool = False


@dataclass
class _Use:
    """How the scenario uses one resource name as one kind."""

    first: str  # where it is first used, for notes
    first_at: At = field(default_factory=At)  # and in the file, for problems
    ops: set[str] = field(default_factory=set)
    mentions: dict[int, int] = field(default_factory=dict)  # task index -> events naming it
    periods: list[int] = field(default_factory=list)  # timer periods, in microseconds
    absolute: bool = False


@dataclass(frozen=True)
class TaskSched:
    """Scheduling settings as rt-app holds them: priority is the nice value for other and batch."""

    policy: str
    priority: int
    runtime: int = 0
    period: int = 0
    deadline: int = 0
    util_min: Optional[int] = None
    util_max: Optional[int] = None


def usec(value: int) -> str:
    """Microseconds written as a duration: 20000 -> `20ms`, 275 -> `275us`."""
    return units.format_duration(value * 1000)


def what_of(value: Any) -> str:
    if isinstance(value, Pairs):
        return "an object"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, bool):
        return str(value).lower()
    if value is None:
        return "null"
    if isinstance(value, str):
        return f"the string {json.dumps(value)}"
    return f"the number {value!r}"


def _clean_name(key: str) -> str:
    """A task's name made a valid thread name: no control characters, spaces or '/'."""
    return "".join("_" if (control_character(c) or c.isspace() or c == "/") else c for c in key) or "task"


def _shared(a: str, b: str) -> int:
    """How many characters `a` and `b` start with alike."""
    return next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))


def _stem(name: str) -> str:
    base = name.replace("\\", "/").rsplit("/", 1)[-1]
    return base.rsplit(".", 1)[0] if "." in base.lstrip(".") else base


def _cut(text: str, limit: int) -> str:
    """`text` cut to `limit` bytes of UTF-8 without splitting a character."""
    return text.encode()[:limit].decode(errors="ignore")


class Reader:
    """One conversion's state, how it says problems and notes, and its typed reads of rt-app values."""

    def __init__(self, file: str, relaxed: Relaxed):
        self.file, self.relaxed = file, relaxed
        self.problems: list[Problem] = []
        self.notes: list[str] = []
        self.uses: dict[str, dict[str, _Use]] = {}
        self.wakes: list[_Wake] = []  # suspends and resumes, decided once every task is read
        self.instances: dict[int, int] = {}  # task index -> its threads (instance)
        self.unique: dict[tuple[int, str], _Use] = {}
        self.pi = False
        self.default_policy = "other"
        self.mem_events = False
        self.realtime = False
        self.thread_names: set[str] = set()
        self.templates: dict[str, tuple[dict[str, Any], At]] = {}  # instance-0 tasks, spawned if a fork names them
        self.forks: list[tuple[str, dict[str, Any], list[Any], At]] = []  # task key, its spawn event, the event's list, where
        self.io_device: Optional[tuple[str, At]] = None
        self.started_keys: set[str] = set()
        self.duration_at = At()  # where global.duration is (or the file's start), for problems of the scenario's duration
        self.tasks_at = At()
        self.task_keys: list[str] = []  # every task's name, for cutting one without making it another's

    # -- reporting

    def locate(self, at: At) -> tuple[int, int]:
        """The line and column in the file of the key or item `at` leads to."""
        return self.relaxed.position(locate_steps(self.relaxed.json, at.steps))

    def problem(self, at: At, message: str) -> None:
        line, col = self.locate(at)
        self.problems.append(Problem(self.file, line, col, str(at), printable(message)))

    def note(self, at: At | str, message: str) -> None:
        where = str(at)
        text = f"{where}: {message}" if where else message
        if text not in self.notes:
            self.notes.append(text)

    # -- typed reads

    def last(self, obj: Pairs, key: str, at: At) -> Optional[tuple[Any, At]]:
        """The value of `key` (the last one, as json-c keeps it) and where it is; repeats are noted."""
        found = [(i, v) for i, (k, v) in enumerate(obj) if k == key]
        if not found:
            return None
        if len(found) > 1:
            self.note(at, f'"{key}" is given {len(found)} times; the last one is used, as rt-app does')
        index, value = found[-1]
        return value, at.key(index, key)

    def integer(self, value: Any, at: At, what: str, low: int = 0, high: int = MAX_INT) -> Optional[int]:
        if isinstance(value, bool) or not isinstance(value, int):
            self.problem(at, f"expected {what}, got {what_of(value)}")
            return None
        if not low <= value <= high:
            self.problem(at, f"{value} is out of range; expected {what} from {low} to {high}")
            return None
        return value

    def string(self, value: Any, at: At, what: str) -> Optional[str]:
        if not isinstance(value, str):
            self.problem(at, f"expected {what}, got {what_of(value)}")
            return None
        return value

    def flag(self, obj: Pairs, key: str, at: At) -> Optional[bool]:
        entry = self.last(obj, key, at)
        if entry is None:
            return None
        value, where = entry
        if not isinstance(value, bool):
            self.problem(where, f"expected true or false, got {what_of(value)}")
            return None
        return value


class Parts(Reader):
    """What a task is made of: its events, scheduling and CPUs, names, and the resources its events use."""

    # -- events

    def events(self, obj: Pairs, at: At, task: int, phase_at: At) -> list[Any]:
        out: list[Any] = []
        for i, (key, value) in enumerate(obj):
            kind = event_kind(key)
            if kind is None:
                continue
            here = at.key(i, key)
            if not re.fullmatch(re.escape(kind) + r"\d*", key):
                self.note(here, f'read as a "{kind}" event, as rt-app reads every key that starts with {kind}')
            for ev in self.event(kind, key, value, here, task, phase_at):
                if isinstance(ev, _Fork):
                    self.forks.append((ev.target, ev.spawn, out, ev.at))
                    ev = ev.spawn
                out.append(Located(ev, here) if type(ev) is dict else ev)
        return out

    def event(self, kind: str, key: str, value: Any, at: At, task: int, phase_at: At) -> list[Any]:
        if kind in NEWER_EVENTS:
            self.note(at, f"{NEWER_EVENTS[kind]}, which this scenario cannot run; left out, so the workload runs without it")
            return []
        if kind == "alloc":
            self.note(at, "rt-app has no alloc event and passes over the key; so does this scenario")
            return []
        if kind in ("run", "runtime", "sleep"):
            us = self.integer(value, at, "a duration in microseconds", 0, MAX_US)
            if us is None:
                return []
            if us == 0:
                self.note(phase_at, f'"{key}": 0 does nothing; left out')
                return []
            return [{kind: usec(us)}]
        if kind == "mem":
            size = self.integer(value, at, "a size in bytes", 0)
            if size is None:
                return []
            if size == 0:
                self.note(phase_at, f'"{key}": 0 bytes does nothing; left out')
                return []
            self.mem_events = True
            return [{kind: units.format_size(size)}]
        if kind == "iorun":
            size = self.integer(value, at, "a size in bytes", 0)
            if not size:
                if size == 0:
                    self.note(phase_at, f'"{key}": 0 bytes does nothing; left out')
                return []
            if self.io_device is not None:
                self.note(self.io_device[1], f"iorun writes to /dev/null here, not to {self.io_device[0]}")
            return [{"iorun": units.format_size(size)}]
        if kind == "fork":
            target = self.string(value, at, "the name of the task to start")
            if target is None:
                return []
            spawn: dict[str, Any] = Located({"spawn": target}, at)
            return [_Fork(self, target, spawn, at)]
        if kind == "yield":
            return ["yield"]
        if kind in ("lock", "unlock"):
            ref = self.string(value, at, "a mutex name")
            return [] if ref is None else [{kind: self.use("mutex", ref, at, task, kind)}]
        if kind in ("signal", "broad"):
            ref = self.string(value, at, "a condition name")
            word = "signal" if kind == "signal" else "broadcast"
            return [] if ref is None else [{word: self.use("cond", ref, at, task, "signal")}]
        if kind in ("wait", "sync"):
            pair = self.wait_refs(value, at)
            if pair is None:
                return []
            cond = self.use("cond", pair[0], at, task, "wait" if kind == "wait" else "both")
            mutex = self.use("mutex", pair[1], at, task, "wait")
            wait = {"wait": {"cond": cond, "mutex": mutex}}
            return [wait] if kind == "wait" else [{"signal": cond}, wait]
        if kind == "barrier":
            ref = self.string(value, at, "a barrier name")
            return [] if ref is None else [{"barrier": self.use("barrier", ref, at, task, "barrier")}]
        if kind in ("suspend", "resume"):
            ref = self.string(value, at, "a thread name")
            if ref is None:
                return []
            if not ref:
                if kind == "resume":
                    self.note(phase_at, f'"{key}" names no thread; left out')
                    return []
                ref = str(at.names[1])  # workgen fills an empty suspend with the thread's own name
            wake = _Wake(kind, ref, at, task)
            self.wakes.append(wake)
            return [wake]
        return self.timer(key, value, at, task, phase_at)

    def wait_refs(self, value: Any, at: At) -> Optional[tuple[str, str]]:
        if not isinstance(value, Pairs):
            self.problem(at, f'expected {{"ref": CONDITION, "mutex": MUTEX}}, got {what_of(value)}')
            return None
        ref, mutex = self.last(value, "ref", at), self.last(value, "mutex", at)
        if ref is None or mutex is None:
            missing = " and ".join(k for k, v in (("ref", ref), ("mutex", mutex)) if v is None)
            self.problem(at, f'{missing} missing; expected {{"ref": CONDITION, "mutex": MUTEX}}')
            return None
        names = self.string(ref[0], ref[1], "a condition name"), self.string(mutex[0], mutex[1], "a mutex name")
        return None if names[0] is None or names[1] is None else (names[0], names[1])

    def timer(self, key: str, value: Any, at: At, task: int, phase_at: At) -> list[Any]:
        if not isinstance(value, Pairs):
            self.problem(at, f'expected {{"ref": NAME, "period": MICROSECONDS}}, got {what_of(value)}')
            return []
        entry = self.last(value, "ref", at)
        ref = self.string(entry[0], entry[1], "a timer name") if entry else "unknown"
        entry = self.last(value, "period", at)
        period = self.integer(entry[0], entry[1], "a period in microseconds", 0, MAX_US) if entry else 0
        entry = self.last(value, "mode", at)
        mode = self.string(entry[0], entry[1], '"relative" or "absolute"') if entry else "relative"
        if ref is None or period is None or mode is None:
            return []
        if mode not in ("relative", "absolute"):
            self.note(
                entry[1] if entry else at,
                f'mode "{mode}" read as {"absolute" if mode.startswith("absolute") else "relative"}, as rt-app does',
            )
        absolute = mode.startswith("absolute")
        if period == 0:
            self.note(phase_at, f'"{key}" has period 0: it never waits; left out')
            return []
        if not self.last(value, "ref", at):
            self.note(at, 'a timer without "ref": rt-app shares one timer named "unknown" among all such events')
        if ref.startswith("unique"):
            use = self.unique.setdefault((task, ref), _Use(str(at), at))
            use.absolute = use.absolute or absolute
            use.mentions[task] = use.mentions.get(task, 0) + 1
            use.periods.append(period)
            return [{"timer": _PrivateTimer(task, ref, period)}]
        named = self.use("timer", ref, at, task, "timer")
        use = self.uses[ref]["timer"]
        use.periods.append(period)
        use.absolute = use.absolute or absolute
        return [{"timer": named}]

    def unique_notes(self, task: int, at: At) -> None:
        refs = sorted(ref for (t, ref) in self.unique if t == task)
        if len(refs) > 1:
            self.note(
                at,
                f"timers {', '.join(repr(r) for r in refs)}: rt-app keeps a release grid per ref in each thread; "
                "here a thread's private timers are one timer with one grid (its first release a period after it is first reached)",
            )

    def use(self, kind: str, name: str, at: At, task: int, op: str) -> _Ref:
        use = self.uses.setdefault(name, {}).setdefault(kind, _Use(str(at), at))
        use.ops.add(op)
        use.mentions[task] = use.mentions.get(task, 0) + 1
        return _Ref(kind, name)

    # -- scheduling and CPUs

    def policy(self, value: Any, at: At) -> Optional[str]:
        word = self.string(value, at, "a policy such as SCHED_OTHER or SCHED_FIFO")
        if word is None:
            return None
        upper = word.strip().upper()
        policy = POLICIES.get(upper) or POLICIES.get("SCHED_" + upper)
        if policy is None:
            self.problem(
                at, f'unknown policy "{word}"; expected one of SCHED_OTHER, SCHED_BATCH, SCHED_IDLE, SCHED_FIFO, SCHED_RR, SCHED_DEADLINE'
            )
        return policy

    def read_sched(self, obj: Pairs, at: At, current: Optional[TaskSched]) -> Optional[TaskSched]:
        """A task's settings (`current` None: defaults from default_policy) or a phase's (None when it sets none)."""
        given = {key: self.last(obj, key, at) for key in SCHED_KEYS}
        if current is not None and not any(given.values()):
            return None
        policy_entry = given["policy"]
        policy = self.policy(*policy_entry) if policy_entry else None
        if policy is None:
            policy = current.policy if current is not None else self.default_policy
        if given["priority"] is not None:
            value, where = given["priority"]
            priority = self.integer(value, where, "a priority (a nice value for SCHED_OTHER)", -MAX_INT)
            if priority is None:
                return None
            if policy in RT_POLICIES and not 1 <= priority <= 99:
                self.problem(where, f"priority {priority} is out of range for SCHED_{policy.upper()}; expected 1..99")
                return None
            if policy in NICE_POLICIES and not -20 <= priority <= 19:
                self.problem(where, f"priority {priority} is the nice value of SCHED_{policy.upper()}; expected -20..19")
                return None
            if policy in ("idle", "deadline"):
                self.note(where, f"priority does not apply to SCHED_{policy.upper()}; left out, as rt-app ignores it")
        elif current is not None and policy_entry is None:
            priority = current.priority  # a phase that names no policy keeps the thread's
        else:
            priority = 0 if policy in NICE_POLICIES else 10  # rt-app's defaults: nice 0, RT priority 10

        dl = {}
        for key in ("dl-runtime", "dl-period", "dl-deadline"):
            entry = given[key]
            if entry is not None:
                dl[key] = self.integer(entry[0], entry[1], "a duration in microseconds", 0, MAX_US)
        if dl and policy != "deadline":
            self.note(at, f"{', '.join(dl)} only apply to SCHED_DEADLINE; left out")
        runtime = period = deadline = 0
        if policy == "deadline":
            if any(v is None for v in dl.values()):
                return None
            if not dl and current is not None and current.policy == "deadline":  # a phase that only changes something else
                runtime, period, deadline = current.runtime, current.period, current.deadline
            else:  # rt-app's defaults: period = runtime, deadline = period
                runtime = dl.get("dl-runtime") or 0
                period = dl.get("dl-period") or runtime
                deadline = dl.get("dl-deadline") or period
            where = given["dl-runtime"][1] if given["dl-runtime"] else (policy_entry[1] if policy_entry else at)
            if runtime <= 0:
                self.problem(where, "SCHED_DEADLINE needs dl-runtime, the runtime budget in microseconds (above 0)")
                return None
            if not runtime <= deadline <= period:
                self.problem(
                    where,
                    f"SCHED_DEADLINE needs dl-runtime <= dl-deadline <= dl-period; got runtime {usec(runtime)}, "
                    f"deadline {usec(deadline)}, period {usec(period)}",
                )
                return None
        clamp: dict[str, Optional[int]] = {"util_min": None, "util_max": None}
        for key in clamp:
            entry = given[key]
            if entry is not None:
                clamp[key] = self.integer(entry[0], entry[1], "a utilisation clamp", 0, 1024)
        if policy == "deadline" and any(v is not None for v in clamp.values()):
            self.note(at, "util_min/util_max do not apply to SCHED_DEADLINE (rt-app does not set them either); left out")
            clamp = {"util_min": None, "util_max": None}
        elif current is not None and policy_entry is None:
            clamp = {k: v if v is not None else getattr(current, k) for k, v in clamp.items()}
        if policy in RT_POLICIES or policy == "deadline":
            self.realtime = True
        return TaskSched(policy, priority, runtime, period, deadline, clamp["util_min"], clamp["util_max"])

    def sched_value(self, sched: TaskSched) -> Any:
        """The scenario's sched: `fifo:10`, `other`, or a mapping when it needs nice, uclamp or deadline values."""
        if sched.policy == "deadline":
            return {
                "policy": "deadline",
                "runtime": usec(sched.runtime),
                "deadline": usec(sched.deadline),
                "period": usec(sched.period),
            }
        out: dict[str, Any] = {"policy": sched.policy}
        if sched.policy in RT_POLICIES:
            out["priority"] = sched.priority
        elif sched.policy in NICE_POLICIES and sched.priority:
            out["nice"] = sched.priority
        for key in ("util_min", "util_max"):
            if getattr(sched, key) is not None:
                out[key] = getattr(sched, key)
        if set(out) == {"policy"}:
            return sched.policy
        if set(out) == {"policy", "priority"}:
            return f"{sched.policy}:{sched.priority}"
        return out

    def cpus(self, obj: Pairs, at: At) -> Optional[list[int]]:
        entry = self.last(obj, "cpus", at)
        if entry is None:
            return None
        value, where = entry
        if not isinstance(value, list) or not value:
            self.problem(where, f"expected a list of CPU numbers such as [0, 2], got {what_of(value) if value != [] else 'an empty list'}")
            return None
        cpus: list[int] = []
        for i, cpu in enumerate(value):
            number = self.integer(cpu, where.item(i), "a CPU number", 0, units.MAX_CPUS - 1)
            if number is None:
                return None
            cpus.append(number)
        return sorted(set(cpus))

    # -- names

    def process_name(self) -> str:
        """The file's base name as a comm; not a thread's name, since the main thread carries it too."""
        stem = re.sub(r"[^A-Za-z0-9_.+-]", "_", _stem(self.file)) or "rtapp"
        name = stem[:COMM_MAX]
        if name in self.thread_names:
            name = stem[: COMM_MAX - len("-app")] + "-app"
            self.note("", f'the process is named "{name}": "{stem[:COMM_MAX]}", after the file, is a thread\'s name')
        elif name != stem:
            self.note("", f'the process is named "{name}", the file name cut to {COMM_MAX} bytes')
        return name

    def scenario_name(self) -> str:
        return re.sub(r"[^A-Za-z0-9_.+-]", "_", _stem(self.file)) or "rtapp"

    def thread_name(self, key: str, count: int, at: At) -> str:
        """A valid, unique thread name for task `key` (room kept for the `-N` that count adds).

        A name cut to its room keeps its head, as the kernel cuts a comm; where that would make it
        another task's (`OMXCallbackDisp1` and `OMXCallbackDisp2` both `OMXCallbackDisp`), it
        keeps what sets it apart from the closest of them too, cutting its head a little shorter for
        it (`OMXCallbackDis1`, `OMXCallbackDis2`); a name still taken gets a number (`_2`)."""
        clean = _clean_name(key)
        room = COMM_MAX - (len(f"-{count - 1}") if count > 1 else 0)
        name = _cut(clean, room)
        rivals = [c for c in map(_clean_name, self.task_keys) if c != clean and _cut(c, room) == name] if name != clean else []
        tail = clean[max((_shared(clean, r) for r in rivals), default=len(clean)) :]  # what sets it apart from the closest
        if tail and len(tail.encode()) <= room // 2:
            name = _cut(clean, room - len(tail.encode())) + tail
        n = 2
        while self._taken(name, count):
            suffix = f"_{n}"
            name = _cut(clean, room - len(suffix)) + suffix
            n += 1
        self.thread_names.update(self._names(name, count))
        if name != key:
            size = len(key.encode("utf-8", "surrogatepass"))  # JSON may hold half a UTF-16 pair, which `clean` replaced
            why = "cut to fit the 15 bytes the kernel keeps" if size > room else "made valid and unique"
            extra = f" with room for -0..-{count - 1}" if count > 1 and size > room else ""
            self.note(at, f'thread name "{printable(key)}" {why}{extra}: {name}')
        return name

    def _names(self, name: str, count: int) -> list[str]:
        return [name] if count == 1 else [f"{name}-{i}" for i in range(count)]

    def _taken(self, name: str, count: int) -> bool:
        return any(n in self.thread_names for n in self._names(name, count))

    def description(self) -> str:
        """What the scenario is, and the rt-app file's first comment when it has one."""
        text = f"Converted from the rt-app workload {_stem(self.file)} by runner import-rtapp."
        comment = first_comment(self.relaxed.source)
        return text + ("\n\n" + comment if comment else "")

    # -- resources

    def wake_objects(self) -> None:
        """Decide what each suspend and resume takes, once every task is read (see `_Wake`)."""
        shared = {w.name for w in self.wakes if {"cond", "mutex"} & set(self.uses.get(w.name, {}))}
        for w in self.wakes:
            if w.name in shared:
                w.shared = True
                self.use("mutex", w.name, w.at, w.task, w.kind)
                self.use("cond", w.name, w.at, w.task, "wait" if w.kind == "suspend" else "signal")
            else:
                self.use("queue", w.name, w.at, w.task, w.kind)
        for name in sorted(shared):
            self.note(
                "",
                f'"{printable(name)}" is suspended on or resumed and also waited on, signalled or locked: its suspends and resumes '
                "take that condition and mutex, as in rt-app (lock, wait or broadcast, unlock; a resume with no thread suspended is lost)",
            )

    def resources(self) -> dict[str, Any]:
        """Every resource the events name, under its final name; set `self.final` for `resolve`."""
        self.wake_objects()
        self.final: dict[tuple[str, str], str] = {}
        taken: set[str] = set()
        out: dict[str, Any] = {}
        for name, kinds in self.uses.items():
            base = re.sub(r"[^A-Za-z0-9_.-]", "_", name) or "unnamed"
            several = len(kinds) > 1
            finals = []
            for kind in kinds:
                want = f"{base}_{kind}" if several else base
                final, n = want, 2
                while final in taken:
                    final, n = f"{want}_{n}", n + 1
                taken.add(final)
                self.final[(kind, name)] = final
                finals.append(final)
                out[final] = Located(self.resource(kind, final, kinds[kind]), kinds[kind].first_at)
            if finals[0] != name and not several:  # several kinds: the note below names each
                why = "letters, digits, _ . - only" if base != name else f"{base} is taken"
                self.note("", f'resource "{printable(name)}" is named {finals[0]} here ({why})')
            if several:
                kinds_used = list(kinds)
                uses = ", a ".join(kinds_used[:-1]) + " and a " + kinds_used[-1]
                self.note("", f'"{printable(name)}" is used as a {uses} (rt-app keeps them apart); here they are {", ".join(finals)}')
        return out

    def resource(self, kind: str, final: str, use: _Use) -> dict[str, Any]:
        if kind == "mutex":
            return {"kind": "mutex", "protocol": "inherit"} if self.pi else {"kind": "mutex"}
        if kind == "timer":
            periods = list(dict.fromkeys(use.periods))
            if len(periods) > 1:
                self.note(
                    use.first,
                    f"timer {final} is given periods {', '.join(usec(p) for p in periods)}: rt-app advances its grid by each event's own; "
                    f"here it keeps {usec(periods[0])}",
                )
            users = sum(self.instances.get(task, 1) for task in use.mentions)
            if users > 1:
                self.note(
                    use.first,
                    f"timer {final} is used by {users} threads: in rt-app they share its ticks (each use moves the timer on "
                    "by a period, so each of them gets some of the ticks, not all); here the named timer releases every one "
                    "of them at every tick",
                )
            return {"kind": "timer", "period": usec(periods[0]), "overrun": "catchup" if use.absolute else "rebase"}
        if kind == "cond" and "signal" not in use.ops and "both" not in use.ops:
            self.note(use.first, f"nothing signals {final}: a wait on it blocks until the run ends, as in rt-app")
        if kind == "queue" and "resume" not in use.ops:
            self.note(use.first, f"nothing resumes {final}: a suspend on it blocks until the run ends, as in rt-app")
        if kind == "queue" and "suspend" not in use.ops:
            self.note(use.first, f"no thread suspends on {final}: its resumes wake nobody")
        if kind == "queue":
            return {"kind": "queue", "pending": "drop"}  # rt-app's resume: lost when no thread is suspended
        if kind == "barrier":
            twice = [t for t, n in use.mentions.items() if n > 1]
            if twice:
                self.note(
                    use.first,
                    f"barrier {final} is named more than once by one task: rt-app counts each mention as a party, "
                    "a barrier here counts each thread once",
                )
        return {"kind": kind}

    def resolve(self, value: Any) -> Any:
        if isinstance(value, _Ref):
            return self.final[(value.kind, value.name)]
        if isinstance(value, _PrivateTimer):
            use = self.unique[(value.task, value.ref)]
            return {"period": usec(value.period_us), "overrun": "catchup" if use.absolute else "rebase"}
        if isinstance(value, dict):
            resolved = {k: self.resolve(v) for k, v in value.items()}
            return Located(resolved, value.at) if isinstance(value, Located) else resolved
        if isinstance(value, list):
            return [e for v in value for e in (self.wake_events(v) if isinstance(v, _Wake) else [self.resolve(v)])]
        return value

    def wake_events(self, wake: _Wake) -> list[dict[str, Any]]:
        if not wake.shared:
            return [Located({wake.kind: self.final[("queue", wake.name)]}, wake.at)]
        mutex, cond = self.final[("mutex", wake.name)], self.final[("cond", wake.name)]
        if wake.kind == "suspend":
            events: list[dict[str, Any]] = [{"lock": mutex}, {"wait": {"cond": cond, "mutex": mutex}}, {"unlock": mutex}]
        else:
            events = [{"lock": mutex}, {"broadcast": cond}, {"unlock": mutex}]
        return [Located(e, wake.at) for e in events]


def unlocated(value: Any, path: Path, origins: dict[Path, At]) -> Any:
    """`value` as plain data, with where each located mapping came from added to `origins` by its path in the scenario."""
    if isinstance(value, dict):
        if isinstance(value, Located):
            origins[path] = value.at
        return {k: unlocated(v, path + (k,), origins) for k, v in value.items()}
    if isinstance(value, list):
        return [unlocated(v, path + (i,), origins) for i, v in enumerate(value)]
    return value
