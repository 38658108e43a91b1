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
  lock also names `X`, they take that condition and mutex instead, as rt-app's do (`rtappevents._Wake`).  `iorun` -> `iorun` (to /dev/null,
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

import re

from runner.errors import Problem, ScenarioError, special_file
from runner.scenario.rtappevents import At
from runner.scenario.rtappjson import BARE_VALUE, Relaxed, line_col, parse_relaxed, relax
from runner.scenario.rtappscenario import Conversion
from runner.scenario.rtapptasks import Converter
from runner.scenario.rtappwords import (
    DEFAULT_DURATION_S,
    EVENTS,
    FOREVER,
    FORK_INSTANCES,
    MAX_BYTES,
    MAX_DURATION_S,
    MAX_INT,
    MAX_US,
    Pairs,
    event_kind,
)
from runner.scenario.yamlsource import byte_position

__all__ = [  # the face of the rt-app conversion: what the loader, the CLI and the tests take from here
    "BARE_VALUE",
    "DEFAULT_DURATION_S",
    "EVENTS",
    "FOREVER",
    "FORK_INSTANCES",
    "MAX_BYTES",
    "MAX_DURATION_S",
    "MAX_INT",
    "MAX_US",
    "Conversion",
    "Pairs",
    "Relaxed",
    "convert",
    "event_kind",
    "parse_relaxed",
    "read",
    "relax",
]


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
        line, col = line_col(text, text.index('"schema"'))
        raise ScenarioError([Problem(name, line, col, "schema", _results_file(head.group(1), name, reader))])
    data, relaxed = parse_relaxed(text, name)
    converter = Converter(name, relaxed)
    if isinstance(data, Pairs):
        schema = [(i, value) for i, (key, value) in enumerate(data) if key == "schema"]
        if schema and isinstance(schema[-1][1], str) and schema[-1][1].startswith("runner.results/"):
            converter.problem(At().key(schema[-1][0], "schema"), _results_file(schema[-1][1], name, reader))
            raise ScenarioError(converter.problems)
    return converter.convert(data)


def _results_file(schema: str, name: str, reader: str) -> str:
    """What to say of a runner results file given where a scenario or an rt-app workload is read."""
    expected, words = _READERS[reader]
    return f"is {schema!r}: a runner results file, not {expected}; {words}; `runner report {name}` re-renders its report"
