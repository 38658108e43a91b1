"""Converting a whole rt-app file: its global settings, each task and its phases, into one scenario.

The top of the conversion: `Converter` reads the file's `global` and `tasks` with the parts
of `runner.scenario.rtappevents` and gives a `Conversion`.
"""

from __future__ import annotations

from typing import Any, Optional

from runner.errors import ScenarioError
from runner.scenario.model import control_character
from runner.scenario.rtappevents import At, Located, Parts, TaskSched, unlocated, usec, what_of
from runner.scenario.rtappscenario import Conversion
from runner.scenario.rtappwords import (
    DEFAULT_DURATION_S,
    FOREVER,
    FORK_INSTANCES,
    LEGACY,
    LEGACY_NOTE,
    MAX_DURATION_S,
    MAX_INT,
    MAX_US,
    PHASE_KEYS,
    TASK_KEYS,
    TASK_UNSUPPORTED,
    Pairs,
    event_kind,
)
from runner.scenario.yamlsource import Path, printable


class Converter(Parts):
    """The whole file: the global settings, each task and its phases, into one scenario."""

    # -- the whole file

    def convert(self, data: Any) -> Conversion:
        root = At()
        if not isinstance(data, Pairs):
            self.problem(root, f'expected an rt-app workload object {{"tasks": {{...}}, "global": {{...}}}}, got {what_of(data)}')
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
                self.problem(global_entry[1], f"expected an object of global settings, got {what_of(global_entry[0])}")
        duration = self.global_settings(glob, global_at)
        lock_pages = self.flag(glob, "lock_pages", global_at)

        tasks_entry = self.last(data, "tasks", root)
        threads: list[dict[str, Any]] = []
        if tasks_entry is None:
            self.problem(root, 'no "tasks" object: an rt-app workload needs at least one task, e.g. {"tasks": {"thread0": {"run": 1000}}}')
        elif not isinstance(tasks_entry[0], Pairs) or not tasks_entry[0]:
            self.problem(
                tasks_entry[1], f"expected an object with one entry per task, got {what_of(tasks_entry[0]) if tasks_entry[0] else 'none'}"
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
        origins: dict[Path, At] = {("duration",): self.duration_at, ("processes", 0): self.tasks_at}
        plain = unlocated(self.resolve(scenario), (), origins)
        return Conversion(plain, list(self.notes), self.file, origins, self.locate)

    def global_settings(self, glob: Pairs, at: At) -> int:
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

    def global_after(self, glob: Pairs, at: At) -> None:
        entry = self.last(glob, "mem_buffer_size", at)
        if entry is not None and self.mem_events:
            self.note(entry[1], "has no equivalent: mem events write a per-thread buffer of the runner's own size")

    # -- one task

    def task(self, index: int, key: str, obj: Any, at: At) -> Optional[dict[str, Any]]:
        if not isinstance(obj, Pairs):
            self.problem(at, f"expected an object describing the task (events, loop, policy, phases...), got {what_of(obj)}")
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
            elif k in TASK_UNSUPPORTED:
                self.note(where, f"{TASK_UNSUPPORTED[k]}; left out")
            elif k not in TASK_KEYS and k not in LEGACY:
                self.note(where, "is not an rt-app task key; ignored (as rt-app does)")

        loop_entry = self.last(obj, "loop", at)
        loop = -1
        if loop_entry is not None:
            given = self.integer(loop_entry[0], loop_entry[1], "a loop count (-1: until the run ends)", -MAX_INT)
            loop = -1 if given is None else given

        phases: list[dict[str, Any]]
        if phases_entry is None:
            events = self.events(obj, at, index, at)
            phases = [Located({"events": events}, at)] if events else []
            work_loop = max(loop, 0) if loop_entry is not None else 0  # rt-app loops a task of bare events forever
        else:
            value, phases_at = phases_entry
            if not isinstance(value, Pairs) or not value:
                self.problem(phases_at, f"expected an object with one entry per phase, got {what_of(value) if value else 'none'}")
                return None
            phases, forever = self.phases(value, phases_at, index, sched, cpus)
            work_loop = 0 if loop < 0 or forever else loop
            if loop == 0:
                self.note(loop_entry[1] if loop_entry else at, "loop 0: rt-app runs none of the phases; the thread only sleeps here")
                phases = []
        name = self.thread_name(key, count, at)
        thread: dict[str, Any] = Located({"name": name}, at)
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
        work: dict[str, Any] = Located({"kind": "phases"}, at)
        if delay:
            work["delay"] = usec(delay)
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

    def legacy(self, obj: Pairs, at: At) -> None:
        keys = [k for k in dict.fromkeys(obj.names()) if k in LEGACY]
        if keys:
            self.note(at, LEGACY_NOTE.format(keys=", ".join(keys)))

    def phases(
        self, obj: Pairs, at: At, task: int, task_sched: Optional[TaskSched], task_cpus: Optional[list[int]]
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
                self.problem(here, f"expected an object of events (and loop, cpus, policy...), got {what_of(body)}")
                continue
            self.legacy(body, here)
            for j, (k, _) in enumerate(body):
                if event_kind(k) is None and k not in PHASE_KEYS and k not in LEGACY:
                    self.note(here.key(j, k), "is not an rt-app phase key; ignored (as rt-app does)")
            loop = 1
            entry = self.last(body, "loop", here)
            if entry is not None:
                value = self.integer(entry[0], entry[1], "a loop count", -MAX_INT)
                loop = value if value is not None else 1
            sched = self.read_sched(body, here, current)
            events = self.events(body, here, task, here)
            phase: dict[str, Any] = Located({}, here)
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
