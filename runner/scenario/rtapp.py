"""Convert an rt-app workload (its relaxed JSON) into a runner scenario with `kind: phases` work.

Pure: text in, plain data and notes out (`runner import-rtapp` reads and writes the files).

Reading.  rt-app files are not strict JSON: they carry `/* */` and `//` comments, trailing
commas, the same key several times in one object (`"run": 1000, ..., "run": 2000`, workgen's
convention; json-c would keep only the last), and bare keys (`"suspend",`, which workgen fills
with the thread's name).  A hand-written pre-pass blanks comments and trailing commas *in place*
and gives a bare key `:""` (`Relaxed.position` maps offsets back, so a JSON error's line and
column are those of the file), then `json.loads` builds every object as `Pairs`, a list of all
its (key, value) pairs in order.  A key given twice that is not an event (`loop`) takes its last
value, as json-c does, with a note.  Event keys are recognised by prefix, in rt-app's own order
(`runtime2` is a runtime, `run0` and `run_fast` are runs, `timer1` a timer).  Positions of keys
are only needed for a problem's `file:line:col`, so they are looked up again in the cleaned text
when a problem is reported, never for a file that converts.

Mapping (rt-app numbers are microseconds; durations are written back with units):

* `global.duration` (s) -> `duration`; -1, 0 or absent (rt-app then runs until every thread
  ends) -> 10s, with a note.  `default_policy` is the policy of tasks without one.
  `pi_enabled` -> `protocol: inherit` on every mutex.  `lock_pages` -> `memory: {lock: true}`
  on the process (rt-app itself only locks for real-time threads, and locks by default when the
  key is absent: both differences are noted).
* Other `global` keys are ignored.  Only two change what the threads do, and only they are
  noted: `calibration` given as a number (rt-app's run then is a fixed amount of work, the
  runner's run is CPU time) and `mem_buffer_size` with mem events (the runner writes a buffer of
  its own size).  `logdir`, `log_basename`, `log_size`, `gnuplot`, `ftrace`, `cumulative_slack`
  shape rt-app's logs and traces only (the runner records its own results); `calibration` as
  `"CPUn"` only says where rt-app calibrates its loop; `io_device` only matters to `iorun`, which
  is noted where it is used; unknown keys (`frag`, `spacing`) are ignored by rt-app too.
* The tasks become the threads of one process named after the file (15 bytes, a valid comm,
  never a thread's name: the main thread carries it), with `start: in_order`: rt-app creates
  its threads one after the other in file order, and here each thread begins once the one
  listed before it has begun (example4's two threads, which resume each other, lost both
  resumes to the race of a common start now and then, and deadlocked).
  `instance: N` -> `count: N` (`instance: 0`: left out unless a fork names it); names are cut to
  15 bytes (room kept for `-N` suffixes; a name the cut would make another's keeps what sets it
  apart, `OMXCallbackDis1`), made unique, and noted.  `policy`/`priority` -> `sched` (priority is the nice value for
  SCHED_OTHER/BATCH, the RT priority for FIFO/RR, default 10 as rt-app);
  `dl-runtime`/`dl-period`/`dl-deadline` -> `{policy: deadline, runtime, deadline, period}`
  (period defaults to runtime, deadline to period); `util_min`/`util_max` go into the sched
  mapping; `cpus` -> `cpus`; `delay` -> work `delay`; the task `loop` -> work `loop` (-1 -> 0,
  until the run ends); each entry of `phases` -> a phase (name, `loop`, per-phase `sched` and
  `cpus`, events in order); a task without `phases` is one phase.
* rt-app returns a phase without `cpus` to the task's CPUs; a phase here keeps the CPUs it has,
  so such phases get the task's `cpus` written out.  A phase `loop` of 0 or less never ends in
  rt-app: the phases after it are left out.
* Events: run, runtime, sleep, mem, lock, unlock, signal, broad (-> broadcast), wait
  (`{ref, mutex}` -> `{cond, mutex}`), sync (-> signal then wait, as rt-app runs it), barrier,
  yield, timer, suspend, resume.  A timer whose ref starts with `unique` is one per rt-app
  instance, that is one per thread here: a private `timer: {period, overrun}`; any other ref is
  a named `kind: timer` resource shared by every thread naming it.  Mode `relative` (rt-app's
  default: the next release is a period after a late one) -> `overrun: rebase`, `absolute` ->
  `overrun: catchup`.  `suspend: X` blocks on, and `resume: X` wakes, the queue `X` (rt-app
  names the thread; an empty suspend is the thread's own) with `pending: drop`: as rt-app's
  resume (a broadcast of the condition X), it wakes every thread suspended at that moment and
  is lost when none is; the cell counts and says what was lost.  Where a wait, sync, signal or
  lock also names `X`, they take that condition and mutex instead, as rt-app's do (see `_Wake`).  `iorun` -> `iorun` (to /dev/null,
  rt-app's default `io_device`; another device is noted).  `fork: task` -> `spawn: task`, where
  the task has `instance: 0` (rt-app starts no thread for it otherwise): it becomes a thread with
  `spawned: true`, `inherit: false` (rt-app's forked threads set their own policy) and `count: 16`
  (rt-app forks 1,024 of a task in all, then exits; noted).  Anything else is left out with a note, as are zero durations and
  sizes (they do nothing).
* Keys rt-app does not read (a typo, `taskgroup`, the old grammar's `exec`/`period`/`lock_order`)
  are noted where they are.  Wrong types and values rt-app or the kernel would refuse (a string
  for a duration, FIFO priority 0, SCHED_DEADLINE without dl-runtime) are problems, all reported
  at once as `file:line:col: key.path: message`.
* Resources are inferred from use and listed under `resources:`.  rt-app keeps one namespace
  per kind, the scenario one for all: a name used as two kinds gets `_mutex`, `_cond`, ...
  suffixes, noted.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, Optional, Union

import yaml

from runner import units
from runner.errors import Problem, ScenarioError, special_file
from runner.scenario.model import COMM_MAX, control_character
from runner.scenario.yamlsource import Document, Mark, Path, byte_position, dotted, load_text, printable

MAX_BYTES = 1 << 20  # rt-app files are a few KiB; a megabyte is not a workload
DEFAULT_DURATION_S = 10
MAX_DURATION_S = 24 * 3600  # the scenario's bound on a cell's duration
MAX_INT = 2**31 - 1  # rt-app reads every number as a C int
FOREVER = MAX_INT  # a phase loop that never ends before the run does
FORK_INSTANCES = 16  # how many threads a forked task can have here (rt-app: 1,024 forks of it in all, then it exits)
MAX_US = 24 * 3600 * 1_000_000  # no event lasts longer than a run

# rt-app's event names, in the order it tests them: a key is the first event it starts with
EVENTS = (
    "lock",
    "unlock",
    "wait",
    "signal",
    "broad",
    "sync",
    "sleep",
    "runtime",
    "run",
    "timer",
    "suspend",
    "resume",
    "mem",
    "iorun",
    "yield",
    "barrier",
    "fork",
    "alloc",
)
_SCHED_KEYS = ("policy", "priority", "dl-runtime", "dl-period", "dl-deadline", "util_min", "util_max")
_TASK_KEYS = {"instance", "cpus", "delay", "loop", "phases", *_SCHED_KEYS}
_PHASE_KEYS = {"loop", "cpus", *_SCHED_KEYS}
_TASK_UNSUPPORTED = {
    "taskgroup": "cgroup task groups have no equivalent here",
    "nodes_membind": "NUMA memory binding has no equivalent here",
    "numa": "NUMA memory binding has no equivalent here",
}
_LEGACY = ("exec", "period", "deadline", "lock_order", "resources")
_LEGACY_NOTE = "{keys}: rt-app's old grammar (exec, period, deadline, lock_order, resources), which rt-app no longer reads; left out"
_POLICIES = {
    "SCHED_OTHER": "other",
    "SCHED_NORMAL": "other",
    "SCHED_BATCH": "batch",
    "SCHED_IDLE": "idle",
    "SCHED_FIFO": "fifo",
    "SCHED_RR": "rr",
    "SCHED_DEADLINE": "deadline",
}
_RT = ("fifo", "rr")
_NICE = ("other", "batch")


class Pairs(list[tuple[str, Any]]):
    """A JSON object as rt-app reads it: every (key, value) pair in order, repeated keys included."""

    def names(self) -> list[str]:
        """The keys, in order, repeats included."""
        return [key for key, _ in self]


def event_kind(key: str) -> Optional[str]:
    """The rt-app event a key names (`run0` -> run, `runtime2` -> runtime, `timer_a` -> timer), or None.

    `lock_order`, of rt-app's old grammar, is not taken for a lock.
    """
    if key in _LEGACY:
        return None
    for name in (*_NEWER_EVENTS, *EVENTS):  # memrun before mem, as rt-app looks them up
        if key.startswith(name):
            return name
    return None


_NEWER_EVENTS = {  # events of rt-app after 1.0 that a scenario has no counterpart for: left out, with a note
    "memrun": "a memory-bandwidth load of rt-app after 1.0",
    "sem_post": "a semaphore of rt-app after 1.0",
    "sem_wait": "a semaphore of rt-app after 1.0",
}


# ---------------------------------------------------------------------------- reading


class _Syntax(Exception):
    def __init__(self, offset: int, message: str):
        super().__init__(message)
        self.offset, self.message = offset, message


BARE_VALUE = ':""'  # what a bare key (`"suspend",`) is given: workgen fills an empty suspend with the thread's name


@dataclass(frozen=True)
class Relaxed:
    """rt-app text made strict JSON, and the way back from its offsets to lines and columns of the file."""

    source: str
    json: str
    inserted: tuple[int, ...] = ()  # offsets in `json` where BARE_VALUE was inserted

    def position(self, offset: int) -> tuple[int, int]:
        """1-based line and column in the file of character `offset` of the JSON text."""
        shift = 0
        for at in self.inserted:
            if offset >= at + len(BARE_VALUE):
                shift += len(BARE_VALUE)
            elif offset >= at:
                offset = at
                break
            else:
                break
        return _line_col(self.source, offset - shift)


def relax(text: str) -> Relaxed:
    """`text` as strict JSON: comments and trailing commas blanked out, bare keys given an empty value.

    Comments become spaces (their line breaks stay) and trailing commas a space, so every other
    character keeps its offset; a key written alone (`"suspend",`, as workgen allows) is followed
    by `:""`, and `Relaxed.position` takes those insertions back out.  Strings are copied as
    written: a `//` inside a string is text.
    """
    out: list[str] = []
    inserted: list[int] = []
    containers: list[str] = []  # the open { and [, innermost last
    last = ""  # the last character that is neither space nor comment
    pending_comma = -1  # offset in `out` of a comma that a closing bracket would make trailing
    i, n = 0, len(text)
    while i < n:
        char = text[i]
        if char == '"':
            end = _string_end(text, i)
            is_key = containers[-1:] == ["{"] and last in ("{", ",")
            out.extend(text[i:end])
            i, last, pending_comma = end, '"', -1
            if is_key and text[_skip_blank(text, i) : _skip_blank(text, i) + 1] in (",", "}"):
                inserted.append(len(out))
                out.extend(BARE_VALUE)
            continue
        if text.startswith("/*", i) or text.startswith("//", i):
            end = _skip_comment(text, i)
            out.extend(c if c in "\r\n" else " " for c in text[i:end])
            i = end
            continue
        if char in "}]":
            if pending_comma >= 0:
                out[pending_comma] = " "
            if containers:
                containers.pop()
        elif char in "{[":
            containers.append(char)
        if char == ",":
            pending_comma = len(out)
        elif not char.isspace():
            pending_comma = -1
        if not char.isspace():
            last = char
        out.append(char)
        i += 1
    return Relaxed(text, "".join(out), tuple(inserted))


def _string_end(text: str, start: int) -> int:
    """Offset after the string that opens at `start` (the end of the text if it never closes)."""
    i, n = start + 1, len(text)
    while i < n and text[i] != '"':
        i += 2 if text[i] == "\\" else 1
    return min(i + 1, n)


def _skip_comment(text: str, start: int) -> int:
    """Offset after the comment that opens at `start`; a /* never closed is an error."""
    if text.startswith("//", start):
        end = text.find("\n", start)
        return len(text) if end < 0 else end
    end = text.find("*/", start + 2)
    if end < 0:
        raise _Syntax(start, "a /* comment is never closed with */")
    return end + 2


def _skip_blank(text: str, i: int) -> int:
    """Offset of the first character from `i` on that is neither space nor comment."""
    while i < len(text):
        if text[i].isspace():
            i += 1
        elif text.startswith("/*", i) or text.startswith("//", i):
            i = _skip_comment(text, i)
        else:
            break
    return i


def _no_constant(word: str) -> Any:
    raise _Syntax(-1, f"{word} is not a number rt-app can read")


def parse_relaxed(text: str, file: str) -> tuple[Any, Relaxed]:
    """rt-app's relaxed JSON as plain data (objects as `Pairs`), and the strict text it was read from.

    Raises ScenarioError with the line and column of the first syntax problem.
    """
    if len(text.encode("utf-8", "surrogatepass")) > MAX_BYTES:
        raise ScenarioError([Problem(file, 1, 1, "", f"file is larger than {MAX_BYTES} bytes; is it really an rt-app workload?")])
    text = " " + text[1:] if text.startswith("\ufeff") else text
    if not text.strip():
        raise ScenarioError([Problem(file, 1, 1, "", 'the file is empty; expected an rt-app workload: {"tasks": {...}}')])
    try:
        relaxed = relax(text)
    except _Syntax as exc:
        line, col = _line_col(text, exc.offset)
        raise ScenarioError([Problem(file, line, col, "", exc.message)]) from None
    try:
        data = json.loads(relaxed.json, object_pairs_hook=Pairs, parse_constant=_no_constant)
    except _Syntax as exc:
        raise ScenarioError([Problem(file, 1, 1, "", exc.message)]) from None
    except json.JSONDecodeError as exc:
        line, col = relaxed.position(exc.pos)
        message = f"not JSON, even with comments, trailing commas and bare keys allowed: {exc.msg}"
        raise ScenarioError([Problem(file, line, col, "", message)]) from None
    except RecursionError:
        raise ScenarioError([Problem(file, 1, 1, "", "nesting is too deep for an rt-app workload")]) from None
    except ValueError as exc:  # a number past Python's limit on digits
        raise ScenarioError([Problem(file, 1, 1, "", printable(f"cannot read the file: {exc}"))]) from None
    return data, relaxed


def _line_col(text: str, offset: int) -> tuple[int, int]:
    return text.count("\n", 0, offset) + 1, offset - (text.rfind("\n", 0, offset) + 1) + 1


_WS = re.compile(r"[ \t\n\r]*")


def _locate(clean: str, steps: tuple[int, ...]) -> int:
    """Offset of the key (in an object) or item (in an array) that `steps` lead to: pair and item indexes."""
    decoder = json.JSONDecoder()

    def ws(i: int) -> int:
        match = _WS.match(clean, i)
        return match.end() if match else i

    def skip_pairs(i: int, count: int) -> int:
        for _ in range(count):
            _, i = decoder.raw_decode(clean, i)  # the key, a JSON string
            _, i = decoder.raw_decode(clean, ws(ws(i) + 1))
            i = ws(ws(i) + 1)
        return i

    try:
        i = at = ws(0)
        for step in steps:
            if clean[i] == "{":
                i = at = skip_pairs(ws(i + 1), step)
                _, i = decoder.raw_decode(clean, i)  # the key, a JSON string
                i = ws(ws(i) + 1)
            elif clean[i] == "[":
                i = ws(i + 1)
                for _ in range(step):
                    _, i = decoder.raw_decode(clean, i)
                    i = ws(ws(i) + 1)
                at = i
            else:
                break
        return at
    except (IndexError, ValueError, RecursionError):
        return 0


# ------------------------------------------------------------------------- conversion


@dataclass(frozen=True)
class _At:
    """Where a value is: its key path as shown to users, and its pair/item indexes in the file."""

    names: tuple[Union[str, int], ...] = ()
    steps: tuple[int, ...] = ()

    def key(self, index: int, name: str) -> _At:
        return _At(self.names + (name,), self.steps + (index,))

    def item(self, index: int) -> _At:
        return _At(self.names + (index,), self.steps + (index,))

    def __str__(self) -> str:
        return dotted(self.names)


class _Located(dict[str, Any]):
    """A mapping of the scenario (a thread, its work, a phase, an event, a resource) and where in the rt-app file it came from."""

    def __init__(self, items: dict[str, Any], at: _At):
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
    first_at: _At = field(default_factory=_At)  # and in the file, for problems
    ops: set[str] = field(default_factory=set)
    mentions: dict[int, int] = field(default_factory=dict)  # task index -> events naming it
    periods: list[int] = field(default_factory=list)  # timer periods, in microseconds
    absolute: bool = False


@dataclass(frozen=True)
class _Sched:
    """Scheduling settings as rt-app holds them: priority is the nice value for other and batch."""

    policy: str
    priority: int
    runtime: int = 0
    period: int = 0
    deadline: int = 0
    util_min: Optional[int] = None
    util_max: Optional[int] = None


@dataclass(frozen=True)
class Conversion:
    """An rt-app workload as a scenario (plain data, as a YAML file holds it) and what did not map exactly."""

    scenario: dict[str, Any]
    notes: list[str]
    source: str = ""
    origins: dict[Path, _At] = field(default_factory=dict)  # where each thread, work, phase, event and resource came from
    locate: Optional[Callable[[_At], tuple[int, int]]] = None  # the line and column of a place in the file

    def document(self, file: str) -> Document:
        """The scenario loaded from its YAML, its problems located in the rt-app file `file` (a direct run of the JSON)."""
        doc = load_text(self.yaml(), f"{file} (as `runner import-rtapp` converts it)")
        if self.locate is None:
            return doc
        return _JsonDocument(file, doc.data, origins=self.origins, locate=self.locate)

    def yaml(self) -> str:
        """The scenario as readable YAML, with the notes as a comment header."""
        origin = f" from {printable(self.source)}" if self.source else ""
        head = [f"# Converted{origin} by `runner import-rtapp` (rt-app workload -> runner scenario)."]
        if self.notes:
            head.append("# What rt-app does that this scenario does differently, or not at all:")
            head.extend(f"#   - {printable(note)}" for note in self.notes)
        body = yaml.dump(_flowing(self.scenario), Dumper=_Dumper, sort_keys=False, default_flow_style=None, width=120, allow_unicode=True)
        return "\n".join(head) + "\n" + body


@dataclass
class _JsonDocument(Document):
    """A converted scenario whose problems are located in the rt-app file it came from.

    A problem the scenario's checks find (a mutex held from one phase into the next) is said at
    the line of the task, phase or event it came from, by the file's key path, with the path of
    the scenario it converts to: that is the line to edit, not one of a text the user never saw."""

    origins: dict[Path, _At] = field(default_factory=dict)
    locate: Callable[[_At], tuple[int, int]] = lambda at: (1, 1)

    def _origin(self, path: Path) -> _At:
        path = tuple(path)
        while path and path not in self.origins:
            path = path[:-1]
        return self.origins.get(path, _At())

    def mark(self, path: Path, *, key: bool = False) -> Mark:
        return Mark(*self.locate(self._origin(path)))

    def problem(self, path: Path, message: str, *, key: bool = False, severity: str = "error") -> Problem:
        at = self._origin(path)
        line, col = self.locate(at)
        scenario = dotted(tuple(path))
        text = f"{message} (the converted scenario's {scenario})" if scenario else message
        return Problem(self.file, line, col, str(at), printable(text), severity)


class _Flow(dict[str, Any]):
    """A mapping written on one line (`{run: 10ms}`), for events and resources."""


class _Dumper(yaml.SafeDumper):
    pass


def _represent_str(dumper: yaml.SafeDumper, value: str) -> yaml.Node:
    style = "|" if "\n" in value else None
    return dumper.represent_scalar("tag:yaml.org,2002:str", value, style=style)


def _represent_flow(dumper: yaml.SafeDumper, value: _Flow) -> yaml.Node:
    return dumper.represent_mapping("tag:yaml.org,2002:map", value.items(), flow_style=True)


_Dumper.add_representer(str, _represent_str)
_Dumper.add_representer(_Flow, _represent_flow)


def _flowing(value: Any, parent: str = "") -> Any:
    """A copy of the scenario with events and resource definitions marked to be written on one line."""
    if isinstance(value, dict):
        if parent == "resources":
            return {k: _Flow(v) if isinstance(v, dict) else v for k, v in value.items()}
        return {k: _flowing(v, k) for k, v in value.items()}
    if isinstance(value, list):
        if parent == "events":
            return [_Flow(e) if isinstance(e, dict) else e for e in value]
        return [_flowing(v) for v in value]
    return value


def _us(value: int) -> str:
    """Microseconds written as a duration: 20000 -> `20ms`, 275 -> `275us`."""
    return units.format_duration(value * 1000)


def _what(value: Any) -> str:
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


def read(path: str) -> str:
    """The text of an rt-app file, at most MAX_BYTES (and one more, so `convert` can say it is too large); problems as ScenarioError."""
    if kind := special_file(path):
        raise ScenarioError([Problem(path, 1, 1, "", f"is {kind}, not a file; expected an rt-app workload (JSON)")])
    try:
        with open(path, "rb") as handle:
            raw = handle.read(MAX_BYTES + 1)
    except OSError as exc:
        raise ScenarioError([Problem(path, 1, 1, "", f"cannot read file: {exc.strerror}")]) from None
    if len(raw) > MAX_BYTES:
        return raw.decode("utf-8", "replace")  # still over MAX_BYTES: convert() says it is too large
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line, col = byte_position(raw, exc.start)
        raise ScenarioError([Problem(path, line, col, "", f"not UTF-8 text: byte {raw[exc.start]:#04x} ({exc.reason})")]) from None


_RESULTS_HEAD = re.compile(r'\ufeff?\s*\{\s*"schema"\s*:\s*"(runner\.results/[^"\\]*)"')
"""The start of a results file as the runner writes it: `schema` first, so found before a large one is parsed."""

_READERS = {
    "import-rtapp": ("an rt-app workload", "`runner import-rtapp` converts rt-app workloads"),
    "validate": ("a scenario", "`runner validate` checks scenario files"),
    "run": ("a scenario", "`runner run` runs scenario files"),
}


def convert(text: str, name: str, reader: str = "import-rtapp") -> Conversion:
    """Convert rt-app workload JSON `text` into a scenario.

    `name` is the file the text came from (a path or a base name): problems are reported as
    `name:line:col`, and the scenario and its process are named after its base name.  Raises
    ScenarioError with every problem found when the text is not a workload rt-app could run.
    `reader` is the command that read the file (import-rtapp, validate, run): a runner results
    file, JSON too, is said to be one in words for that command, not to lack rt-app's "tasks".
    """
    head = _RESULTS_HEAD.match(text)  # before the size check: a results file of a large matrix is past MAX_BYTES
    if head:
        line, col = _line_col(text, text.index('"schema"'))
        raise ScenarioError([Problem(name, line, col, "schema", _results_file(head.group(1), name, reader))])
    data, relaxed = parse_relaxed(text, name)
    converter = _Converter(name, relaxed)
    if isinstance(data, Pairs):
        schema = [(i, value) for i, (key, value) in enumerate(data) if key == "schema"]
        if schema and isinstance(schema[-1][1], str) and schema[-1][1].startswith("runner.results/"):
            converter.problem(_At().key(schema[-1][0], "schema"), _results_file(schema[-1][1], name, reader))
            raise ScenarioError(converter.problems)
    return converter.convert(data)


def _results_file(schema: str, name: str, reader: str) -> str:
    """What to say of a runner results file given where a scenario or an rt-app workload is read."""
    expected, words = _READERS[reader]
    return f"is {schema!r}: a runner results file, not {expected}; {words}; `runner report {name}` re-renders its report"


class _Converter:
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
        self.templates: dict[str, tuple[dict[str, Any], _At]] = {}  # instance-0 tasks, spawned if a fork names them
        self.forks: list[tuple[str, dict[str, Any], list[Any], _At]] = []  # task key, its spawn event, the event's list, where
        self.io_device: Optional[tuple[str, _At]] = None
        self.started_keys: set[str] = set()
        self.duration_at = _At()  # where global.duration is (or the file's start), for problems of the scenario's duration
        self.tasks_at = _At()
        self.task_keys: list[str] = []  # every task's name, for cutting one without making it another's

    # -- reporting

    def locate(self, at: _At) -> tuple[int, int]:
        """The line and column in the file of the key or item `at` leads to."""
        return self.relaxed.position(_locate(self.relaxed.json, at.steps))

    def problem(self, at: _At, message: str) -> None:
        line, col = self.locate(at)
        self.problems.append(Problem(self.file, line, col, str(at), printable(message)))

    def note(self, at: _At | str, message: str) -> None:
        where = str(at)
        text = f"{where}: {message}" if where else message
        if text not in self.notes:
            self.notes.append(text)

    # -- typed reads

    def last(self, obj: Pairs, key: str, at: _At) -> Optional[tuple[Any, _At]]:
        """The value of `key` (the last one, as json-c keeps it) and where it is; repeats are noted."""
        found = [(i, v) for i, (k, v) in enumerate(obj) if k == key]
        if not found:
            return None
        if len(found) > 1:
            self.note(at, f'"{key}" is given {len(found)} times; the last one is used, as rt-app does')
        index, value = found[-1]
        return value, at.key(index, key)

    def integer(self, value: Any, at: _At, what: str, low: int = 0, high: int = MAX_INT) -> Optional[int]:
        if isinstance(value, bool) or not isinstance(value, int):
            self.problem(at, f"expected {what}, got {_what(value)}")
            return None
        if not low <= value <= high:
            self.problem(at, f"{value} is out of range; expected {what} from {low} to {high}")
            return None
        return value

    def string(self, value: Any, at: _At, what: str) -> Optional[str]:
        if not isinstance(value, str):
            self.problem(at, f"expected {what}, got {_what(value)}")
            return None
        return value

    def flag(self, obj: Pairs, key: str, at: _At) -> Optional[bool]:
        entry = self.last(obj, key, at)
        if entry is None:
            return None
        value, where = entry
        if not isinstance(value, bool):
            self.problem(where, f"expected true or false, got {_what(value)}")
            return None
        return value

    # -- the whole file

    def convert(self, data: Any) -> Conversion:
        root = _At()
        if not isinstance(data, Pairs):
            self.problem(root, f'expected an rt-app workload object {{"tasks": {{...}}, "global": {{...}}}}, got {_what(data)}')
            raise ScenarioError(self.problems)
        for key in data.names():
            if key not in ("tasks", "global", "resources"):
                self.note(root, f'"{key}" is not an rt-app section; ignored')
        global_entry = self.last(data, "global", root)
        glob = Pairs()
        global_at = root.key(0, "global")
        if global_entry is not None:
            if isinstance(global_entry[0], Pairs):
                glob, global_at = global_entry
            else:
                self.problem(global_entry[1], f"expected an object of global settings, got {_what(global_entry[0])}")
        duration = self.global_settings(glob, global_at)
        lock_pages = self.flag(glob, "lock_pages", global_at)

        tasks_entry = self.last(data, "tasks", root)
        threads: list[dict[str, Any]] = []
        if tasks_entry is None:
            self.problem(root, 'no "tasks" object: an rt-app workload needs at least one task, e.g. {"tasks": {"thread0": {"run": 1000}}}')
        elif not isinstance(tasks_entry[0], Pairs) or not tasks_entry[0]:
            self.problem(
                tasks_entry[1], f"expected an object with one entry per task, got {_what(tasks_entry[0]) if tasks_entry[0] else 'none'}"
            )
        else:
            tasks, tasks_at = tasks_entry
            self.tasks_at = tasks_at
            self.task_keys = tasks.names()
            for index, (key, value) in enumerate(tasks):
                thread = self.task(index, key, value, tasks_at.key(index, key))
                if thread is not None:
                    threads.append(thread)
            threads.extend(self.spawned(threads))
            if not any(not t.get("spawned") for t in threads) and not self.problems:
                self.problem(tasks_at, "no task is left to run (every one has instance 0)")
        self.global_after(glob, global_at)
        resources = self.resources()
        if self.problems:
            raise ScenarioError(self.problems)

        process: dict[str, Any] = {"name": self.process_name()}
        if sum(1 for t in threads if not t.get("spawned")) > 1:
            process["start"] = "in_order"  # as rt-app creates its threads
        if lock_pages:
            process["memory"] = {"lock": True}
            if not self.realtime:
                self.note(
                    "global.lock_pages",
                    "rt-app locks pages for real-time threads only, and these are all SCHED_OTHER/BATCH/IDLE; the process is locked here",
                )
        elif lock_pages is None and self.realtime:
            self.note(
                "global",
                "lock_pages is not set: rt-app then locks its real-time threads' pages (its default is true, whatever its tutorial says); "
                "memory is not locked here, add memory: {lock: true} to the process to match",
            )
        process["threads"] = threads
        scenario: dict[str, Any] = {
            "name": self.scenario_name(),
            "description": self.description(),
            "duration": f"{duration}s",
        }
        if resources:
            scenario["resources"] = resources
        scenario["processes"] = [process]
        origins: dict[Path, _At] = {("duration",): self.duration_at, ("processes", 0): self.tasks_at}
        plain = _unlocated(self.resolve(scenario), (), origins)
        return Conversion(plain, list(self.notes), self.file, origins, self.locate)

    def global_settings(self, glob: Pairs, at: _At) -> int:
        """Read the global keys that change the scenario; return the duration in seconds."""
        duration = DEFAULT_DURATION_S
        entry = self.last(glob, "duration", at)
        self.duration_at = entry[1] if entry else at
        given = self.integer(entry[0], entry[1], "a whole number of seconds (-1: until the threads end)", -MAX_INT) if entry else -1
        if given is not None and given > 0:
            duration = given
            if given > MAX_DURATION_S:
                duration = MAX_DURATION_S
                self.note(entry[1] if entry else at, f"{given}s is longer than a scenario may run; cut to {MAX_DURATION_S}s (24h)")
        elif given is not None:
            self.note(
                "global.duration",
                f"{given if entry else 'not set'}: rt-app then runs until every thread ends (or forever); "
                f"the scenario runs {DEFAULT_DURATION_S}s, change its duration to suit",
            )
        entry = self.last(glob, "default_policy", at)
        if entry is not None:
            policy = self.policy(entry[0], entry[1])
            if policy is not None:
                self.default_policy = policy
        self.pi = bool(self.flag(glob, "pi_enabled", at))
        entry = self.last(glob, "io_device", at)
        if entry is not None and entry[0] != "/dev/null":
            self.io_device = (str(entry[0]), entry[1])
        entry = self.last(glob, "calibration", at)
        if entry is not None and isinstance(entry[0], int) and not isinstance(entry[0], bool):
            self.note(
                entry[1],
                f"a fixed calibration ({entry[0]} ns per loop) makes rt-app's run a fixed amount of work; "
                "run burns that much thread CPU time here, whatever the CPU's speed",
            )
        return duration

    def global_after(self, glob: Pairs, at: _At) -> None:
        entry = self.last(glob, "mem_buffer_size", at)
        if entry is not None and self.mem_events:
            self.note(entry[1], "has no equivalent: mem events write a per-thread buffer of the runner's own size")

    # -- one task

    def task(self, index: int, key: str, obj: Any, at: _At) -> Optional[dict[str, Any]]:
        if not isinstance(obj, Pairs):
            self.problem(at, f"expected an object describing the task (events, loop, policy, phases...), got {_what(obj)}")
            return None
        count, template = 1, False
        entry = self.last(obj, "instance", at)
        if entry is not None:
            value = self.integer(entry[0], entry[1], "a whole number of threads", 0)
            template = value == 0  # started only by a fork, if one names it
            count = value or 1

        sched = self.read_sched(obj, at, None)
        cpus = self.cpus(obj, at)
        delay = 0
        entry = self.last(obj, "delay", at)
        if entry is not None:
            delay = self.integer(entry[0], entry[1], "a delay in microseconds", 0, MAX_US) or 0
        phases_entry = self.last(obj, "phases", at)
        self.legacy(obj, at)
        for i, (k, _) in enumerate(obj):
            where = at.key(i, k)
            if event_kind(k) is not None:
                if phases_entry is not None:
                    self.note(where, "an event beside phases: rt-app ignores it, and so does this scenario")
            elif k in _TASK_UNSUPPORTED:
                self.note(where, f"{_TASK_UNSUPPORTED[k]}; left out")
            elif k not in _TASK_KEYS and k not in _LEGACY:
                self.note(where, "is not an rt-app task key; ignored (as rt-app does)")

        loop_entry = self.last(obj, "loop", at)
        loop = -1
        if loop_entry is not None:
            given = self.integer(loop_entry[0], loop_entry[1], "a loop count (-1: until the run ends)", -MAX_INT)
            loop = -1 if given is None else given

        phases: list[dict[str, Any]]
        if phases_entry is None:
            events = self.events(obj, at, index, at)
            phases = [_Located({"events": events}, at)] if events else []
            work_loop = max(loop, 0) if loop_entry is not None else 0  # rt-app loops a task of bare events forever
        else:
            value, phases_at = phases_entry
            if not isinstance(value, Pairs) or not value:
                self.problem(phases_at, f"expected an object with one entry per phase, got {_what(value) if value else 'none'}")
                return None
            phases, forever = self.phases(value, phases_at, index, sched, cpus)
            work_loop = 0 if loop < 0 or forever else loop
            if loop == 0:
                self.note(loop_entry[1] if loop_entry else at, "loop 0: rt-app runs none of the phases; the thread only sleeps here")
                phases = []
        name = self.thread_name(key, count, at)
        thread: dict[str, Any] = _Located({"name": name}, at)
        self.instances[index] = count
        if count > 1:
            thread["count"] = count
        if sched is not None:
            thread["sched"] = self.sched_value(sched)
        if cpus is not None:
            thread["cpus"] = cpus
        if not phases:
            if not (loop == 0 and phases_entry is not None):
                self.note(at, "has no event left to run; the thread only sleeps here")
            thread["work"] = {"kind": "sleep"}
            return thread
        work: dict[str, Any] = _Located({"kind": "phases"}, at)
        if delay:
            work["delay"] = _us(delay)
        work["loop"] = work_loop
        work["phases"] = phases
        thread["work"] = work
        self.unique_notes(index, at)
        if template:
            self.templates[key] = (thread, at)
            return None
        self.started_keys.add(key)
        return thread

    def spawned(self, started: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """rt-app's fork as spawn events: the instance-0 tasks they name become threads created by spawns."""
        out: list[dict[str, Any]] = []
        for target, spawn, events, at in self.forks:
            found = self.templates.get(target)
            if found is None:
                why = "a task started at the start (rt-app would start another)" if target in self.started_keys else None
                self.note(at, f"fork of {printable(target)!r}: {why or 'no task of instance 0 has that name'}; left out")
                events.remove(spawn)
                continue
            thread, _ = found
            spawn["spawn"] = thread["name"]
            if not thread.get("spawned"):
                thread.update({"spawned": True, "count": FORK_INSTANCES, "inherit": False})
                self.note(
                    at,
                    f"rt-app forks a new thread of {printable(target)!r} each time (1,024 of it in all, then rt-app exits); "
                    f"here it can be spawned {FORK_INSTANCES} times (count), later spawns are counted as dropped",
                )
                out.append(thread)
        for thread, at in self.templates.values():
            if not thread.get("spawned"):
                self.note(at, "instance 0: rt-app starts no thread for this task and no fork names it; left out")
        return out

    def legacy(self, obj: Pairs, at: _At) -> None:
        keys = [k for k in dict.fromkeys(obj.names()) if k in _LEGACY]
        if keys:
            self.note(at, _LEGACY_NOTE.format(keys=", ".join(keys)))

    def phases(
        self, obj: Pairs, at: _At, task: int, task_sched: Optional[_Sched], task_cpus: Optional[list[int]]
    ) -> tuple[list[dict[str, Any]], bool]:
        """The phases of a task, and whether one of them never ends (rt-app phase loop 0 or less)."""
        out: list[dict[str, Any]] = []
        names: set[str] = set()
        current = task_sched
        own_cpus = [self.cpus(body, at.key(i, k)) if isinstance(body, Pairs) else None for i, (k, body) in enumerate(obj)]
        any_cpus = any(c is not None for c in own_cpus)
        reverted: list[str] = []
        endless = False
        for i, (key, body) in enumerate(obj):
            here = at.key(i, key)
            if not isinstance(body, Pairs):
                self.problem(here, f"expected an object of events (and loop, cpus, policy...), got {_what(body)}")
                continue
            self.legacy(body, here)
            for j, (k, _) in enumerate(body):
                if event_kind(k) is None and k not in _PHASE_KEYS and k not in _LEGACY:
                    self.note(here.key(j, k), "is not an rt-app phase key; ignored (as rt-app does)")
            loop = 1
            entry = self.last(body, "loop", here)
            if entry is not None:
                value = self.integer(entry[0], entry[1], "a loop count", -MAX_INT)
                loop = value if value is not None else 1
            sched = self.read_sched(body, here, current)
            events = self.events(body, here, task, here)
            phase: dict[str, Any] = _Located({}, here)
            base = "".join("_" if control_character(c) else c for c in key).strip() or f"p{i}"
            name, n = base, 2
            while name in names:
                name, n = f"{base}_{n}", n + 1
            if name != key:
                why = (
                    f'a second phase named "{printable(key)}"' if base == key else f'phase name "{printable(key)}" is empty or unprintable'
                )
                self.note(here, f"{why}; named {name} here")
            names.add(name)
            phase["name"] = name
            forever = loop <= 0
            if forever and out:
                phase["loop"] = FOREVER
                self.note(here, f"loop {loop}: rt-app repeats this phase until the run ends; written as loop {FOREVER}")
            elif loop != 1 and not forever:
                phase["loop"] = loop
            if sched is not None:
                phase["sched"] = self.sched_value(sched)
                current = sched
            cpus = own_cpus[i]
            if cpus is not None:
                phase["cpus"] = cpus
            elif any_cpus:  # rt-app sets a phase without cpus back to the task's
                if task_cpus is not None:
                    phase["cpus"] = task_cpus
                else:
                    reverted.append(name)
            if not events:
                self.note(here, "has no event left to run; left out" + (" (with its sched and cpus)" if sched or cpus else ""))
            else:
                phase["events"] = events
                out.append(phase)
            if forever:
                rest = [k for k, _ in obj[i + 1 :]]
                if rest:
                    self.note(here, f"loop {loop} never ends in rt-app, so it never reaches {', '.join(rest)}; left out")
                if len(out) == 1 and "events" in phase:  # the first phase: the whole work repeats until the run ends
                    phase.pop("loop", None)
                    endless = True
                break
        if reverted:
            self.note(
                at,
                f"{', '.join(reverted)}: rt-app runs a phase without cpus on every CPU; here it keeps the CPUs of the phase before "
                "(give the task cpus to set)",
            )
        return out, endless

    # -- events

    def events(self, obj: Pairs, at: _At, task: int, phase_at: _At) -> list[Any]:
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
                out.append(_Located(ev, here) if type(ev) is dict else ev)
        return out

    def event(self, kind: str, key: str, value: Any, at: _At, task: int, phase_at: _At) -> list[Any]:
        if kind in _NEWER_EVENTS:
            self.note(at, f"{_NEWER_EVENTS[kind]}, which this scenario cannot run; left out, so the workload runs without it")
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
            return [{kind: _us(us)}]
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
            spawn: dict[str, Any] = _Located({"spawn": target}, at)
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

    def wait_refs(self, value: Any, at: _At) -> Optional[tuple[str, str]]:
        if not isinstance(value, Pairs):
            self.problem(at, f'expected {{"ref": CONDITION, "mutex": MUTEX}}, got {_what(value)}')
            return None
        ref, mutex = self.last(value, "ref", at), self.last(value, "mutex", at)
        if ref is None or mutex is None:
            missing = " and ".join(k for k, v in (("ref", ref), ("mutex", mutex)) if v is None)
            self.problem(at, f'{missing} missing; expected {{"ref": CONDITION, "mutex": MUTEX}}')
            return None
        names = self.string(ref[0], ref[1], "a condition name"), self.string(mutex[0], mutex[1], "a mutex name")
        return None if names[0] is None or names[1] is None else (names[0], names[1])

    def timer(self, key: str, value: Any, at: _At, task: int, phase_at: _At) -> list[Any]:
        if not isinstance(value, Pairs):
            self.problem(at, f'expected {{"ref": NAME, "period": MICROSECONDS}}, got {_what(value)}')
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

    def unique_notes(self, task: int, at: _At) -> None:
        refs = sorted(ref for (t, ref) in self.unique if t == task)
        if len(refs) > 1:
            self.note(
                at,
                f"timers {', '.join(repr(r) for r in refs)}: rt-app keeps a release grid per ref in each thread; "
                "here a thread's private timers are one timer with one grid (its first release a period after it is first reached)",
            )

    def use(self, kind: str, name: str, at: _At, task: int, op: str) -> _Ref:
        use = self.uses.setdefault(name, {}).setdefault(kind, _Use(str(at), at))
        use.ops.add(op)
        use.mentions[task] = use.mentions.get(task, 0) + 1
        return _Ref(kind, name)

    # -- scheduling and CPUs

    def policy(self, value: Any, at: _At) -> Optional[str]:
        word = self.string(value, at, "a policy such as SCHED_OTHER or SCHED_FIFO")
        if word is None:
            return None
        upper = word.strip().upper()
        policy = _POLICIES.get(upper) or _POLICIES.get("SCHED_" + upper)
        if policy is None:
            self.problem(
                at, f'unknown policy "{word}"; expected one of SCHED_OTHER, SCHED_BATCH, SCHED_IDLE, SCHED_FIFO, SCHED_RR, SCHED_DEADLINE'
            )
        return policy

    def read_sched(self, obj: Pairs, at: _At, current: Optional[_Sched]) -> Optional[_Sched]:
        """A task's settings (`current` None: defaults from default_policy) or a phase's (None when it sets none)."""
        given = {key: self.last(obj, key, at) for key in _SCHED_KEYS}
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
            if policy in _RT and not 1 <= priority <= 99:
                self.problem(where, f"priority {priority} is out of range for SCHED_{policy.upper()}; expected 1..99")
                return None
            if policy in _NICE and not -20 <= priority <= 19:
                self.problem(where, f"priority {priority} is the nice value of SCHED_{policy.upper()}; expected -20..19")
                return None
            if policy in ("idle", "deadline"):
                self.note(where, f"priority does not apply to SCHED_{policy.upper()}; left out, as rt-app ignores it")
        elif current is not None and policy_entry is None:
            priority = current.priority  # a phase that names no policy keeps the thread's
        else:
            priority = 0 if policy in _NICE else 10  # rt-app's defaults: nice 0, RT priority 10

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
                    f"SCHED_DEADLINE needs dl-runtime <= dl-deadline <= dl-period; got runtime {_us(runtime)}, "
                    f"deadline {_us(deadline)}, period {_us(period)}",
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
        if policy in _RT or policy == "deadline":
            self.realtime = True
        return _Sched(policy, priority, runtime, period, deadline, clamp["util_min"], clamp["util_max"])

    def sched_value(self, sched: _Sched) -> Any:
        """The scenario's sched: `fifo:10`, `other`, or a mapping when it needs nice, uclamp or deadline values."""
        if sched.policy == "deadline":
            return {"policy": "deadline", "runtime": _us(sched.runtime), "deadline": _us(sched.deadline), "period": _us(sched.period)}
        out: dict[str, Any] = {"policy": sched.policy}
        if sched.policy in _RT:
            out["priority"] = sched.priority
        elif sched.policy in _NICE and sched.priority:
            out["nice"] = sched.priority
        for key in ("util_min", "util_max"):
            if getattr(sched, key) is not None:
                out[key] = getattr(sched, key)
        if set(out) == {"policy"}:
            return sched.policy
        if set(out) == {"policy", "priority"}:
            return f"{sched.policy}:{sched.priority}"
        return out

    def cpus(self, obj: Pairs, at: _At) -> Optional[list[int]]:
        entry = self.last(obj, "cpus", at)
        if entry is None:
            return None
        value, where = entry
        if not isinstance(value, list) or not value:
            self.problem(where, f"expected a list of CPU numbers such as [0, 2], got {_what(value) if value != [] else 'an empty list'}")
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

    def thread_name(self, key: str, count: int, at: _At) -> str:
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
        comment = _first_comment(self.relaxed.source)
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
                out[final] = _Located(self.resource(kind, final, kinds[kind]), kinds[kind].first_at)
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
                    f"timer {final} is given periods {', '.join(_us(p) for p in periods)}: rt-app advances its grid by each event's own; "
                    f"here it keeps {_us(periods[0])}",
                )
            users = sum(self.instances.get(task, 1) for task in use.mentions)
            if users > 1:
                self.note(
                    use.first,
                    f"timer {final} is used by {users} threads: in rt-app they share its ticks (each use moves the timer on "
                    "by a period, so each of them gets some of the ticks, not all); here the named timer releases every one "
                    "of them at every tick",
                )
            return {"kind": "timer", "period": _us(periods[0]), "overrun": "catchup" if use.absolute else "rebase"}
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
            return {"period": _us(value.period_us), "overrun": "catchup" if use.absolute else "rebase"}
        if isinstance(value, dict):
            resolved = {k: self.resolve(v) for k, v in value.items()}
            return _Located(resolved, value.at) if isinstance(value, _Located) else resolved
        if isinstance(value, list):
            return [e for v in value for e in (self.wake_events(v) if isinstance(v, _Wake) else [self.resolve(v)])]
        return value

    def wake_events(self, wake: _Wake) -> list[dict[str, Any]]:
        if not wake.shared:
            return [_Located({wake.kind: self.final[("queue", wake.name)]}, wake.at)]
        mutex, cond = self.final[("mutex", wake.name)], self.final[("cond", wake.name)]
        if wake.kind == "suspend":
            events: list[dict[str, Any]] = [{"lock": mutex}, {"wait": {"cond": cond, "mutex": mutex}}, {"unlock": mutex}]
        else:
            events = [{"lock": mutex}, {"broadcast": cond}, {"unlock": mutex}]
        return [_Located(e, wake.at) for e in events]


def _unlocated(value: Any, path: Path, origins: dict[Path, _At]) -> Any:
    """`value` as plain data, with where each located mapping came from added to `origins` by its path in the scenario."""
    if isinstance(value, dict):
        if isinstance(value, _Located):
            origins[path] = value.at
        return {k: _unlocated(v, path + (k,), origins) for k, v in value.items()}
    if isinstance(value, list):
        return [_unlocated(v, path + (i,), origins) for i, v in enumerate(value)]
    return value


def _comments(text: str) -> Iterator[str]:
    """The comments of rt-app text, in order, without their markers."""
    i, n = 0, len(text)
    while i < n:
        char = text[i]
        if char == '"':
            i += 1
            while i < n and text[i] != '"':
                i += 2 if text[i] == "\\" else 1
        elif text.startswith("/*", i):
            end = text.find("*/", i + 2)
            end = n if end < 0 else end
            yield text[i + 2 : end]
            i = end + 1
        elif text.startswith("//", i):
            end = text.find("\n", i)
            end = n if end < 0 else end
            yield text[i + 2 : end]
            i = end
        i += 1


def _first_comment(text: str) -> str:
    """The file's first comment as plain lines (its ` * ` margins removed), or empty."""
    for comment in _comments(text):
        lines = [re.sub(r"^\s*\*? ?", "", line).rstrip() for line in comment.splitlines()]
        body = "\n".join(lines).strip()
        body = "".join(c for c in body if c in "\n\t" or not control_character(c))
        if body:
            return body
    return ""
