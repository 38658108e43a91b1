"""`runner watch`: measure processes that are already running, from outside, as a cell measures a program.

"How does my running robot behave" is one command: the named processes' threads are
followed for the duration exactly as a scenario's `command:` programs are (the monitor
lists their threads, reads their counters from /proc, and applies thread rules only when
asked with `--rule`), the scheduler is traced as a run traces it (wake-up latency from
sched_waking to running, preemptions and who preempted, migrations; `--no-trace` leaves it
out, and where tracefs or the rights are missing the cell says why), and the same
results.json and report are written.  Nothing is started and, without rules, nothing is
changed.
"""

from __future__ import annotations

import os
import re
import time
from collections.abc import Callable
from datetime import datetime, timezone

from runner import units
from runner.errors import UsageError
from runner.results.document import CellResult, PermissionsInfo, RunDocument, ScenarioInfo, Status, ps_rows, worst
from runner.results.pstable import ThreadRow
from runner.run import kernel, tracing
from runner.run.evaluate import degradation
from runner.run.external import Monitor, ProgramRun
from runner.run.outside import outcome
from runner.run.traced import Task, apply
from runner.run.traced import warnings as trace_warnings
from runner.scenario.model import ProgramSpec, ThreadRule
from runner.scenario.plan import Settings
from runner.scenario.typed import Invalid

RULE_FORM = "PATTERN=SCHED, PATTERN@CPUS or PATTERN=SCHED@CPUS, e.g. 'ctl_loop=fifo:80@1'"
WATCH_CELL = "watch"


def parse_rule(text: str) -> ThreadRule:
    """`ctl_*=fifo:80@1` -> a thread rule; UsageError naming the form otherwise."""
    match = re.fullmatch(r"([^=@]+)(?:=([^@]+))?(?:@(.+))?", text)
    if not match or (match.group(2) is None and match.group(3) is None):
        raise UsageError(f"runner watch: --rule {text!r}: expected {RULE_FORM}")
    data: dict[str, object] = {"match": match.group(1)}
    if match.group(2) is not None:
        data["sched"] = match.group(2)
    if match.group(3) is not None:
        data["cpus"] = match.group(3)
    try:
        return ThreadRule.parse(data)
    except Invalid as exc:
        what = "; ".join(f"{'.'.join(str(x) for x in issue.path) or 'rule'}: {issue.message}" for issue in exc.issues)
        raise UsageError(f"runner watch: --rule {text!r}: {what}") from None


def resolve_targets(targets: list[str]) -> list[int]:
    """PIDs of the targets: a number is a PID that must be alive, a name every live process whose COMMAND it is."""
    pids: list[int] = []
    for target in targets:
        try:
            pid = units.parse_pid(target)  # ASCII digits; anything else is a name (`٣` may be one)
        except units.UnitError as exc:
            raise UsageError(f"runner watch: {exc}") from None
        if pid is not None:
            if not kernel.process_alive(pid):
                raise UsageError(f"runner watch: no live process has PID {target}")
            found = [pid]
        else:
            found = kernel.find_pids(target)
            if not found:
                raise UsageError(f"runner watch: no live process is named {target!r} (its COMMAND, as ps -C selects it)")
        if found == [os.getpid()]:
            raise UsageError(f"runner watch: {target} is this runner itself; name the processes to watch")
        pids += [p for p in found if p not in pids and p != os.getpid()]
    return pids


def _spec(pid: int, rules: list[ThreadRule]) -> ProgramSpec:
    """A program spec for a process the runner did not start: its name and command line as the kernel has them."""
    comm = kernel.thread_comm(pid, pid) or str(pid)
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as handle:
            argv = [os.fsdecode(a) for a in handle.read().split(b"\0") if a]
    except OSError:
        argv = []
    name = re.sub(r"[\s/]", "_", comm) or str(pid)
    return ProgramSpec(name=name, command=argv or [comm], threads=rules, grace=0)


def watch(
    pids: list[int], duration_ns: int, folder: str, rules: list[ThreadRule], stop_requested: Callable[[], bool], trace: bool = True
) -> RunDocument:
    """Follow the processes for `duration_ns` (or until stopped) and return the run's document, one cell long.

    `trace`: trace the scheduler for them (tracefs), as a run traces its cells.
    """
    online = kernel.online_cpus()
    start = kernel.current_settings()
    runs = []
    for pid in pids:
        run = ProgramRun(_spec(pid, rules), folder, start, online)
        run.attach(pid)
        runs.append(run)
    started_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
    tracer = tracing.open_trace(pids) if trace else None
    try:
        return _watched(runs, duration_ns, start, started_at, stop_requested, tracer)
    finally:
        if isinstance(tracer, tracing.Tracer):
            tracer.close()


def _watched(
    runs: list[ProgramRun],
    duration_ns: int,
    start: Settings,
    started_at: str,
    stop_requested: Callable[[], bool],
    tracer: tracing.Tracer | tracing.TraceUnavailable | None,
) -> RunDocument:
    monitor = Monitor(runs)
    monitor.start()
    # The window opens once every thread there is listed: one listed after its start counts as born in the window,
    # from zero, and a process's whole life before the watch was reported as the watch's.
    began = time.monotonic_ns()
    monitor.window_start = began
    if isinstance(tracer, tracing.Tracer):
        tracer.window(began, None)  # the reader holds events back 10 ms: none of the window is counted before it is set
    table: list[ThreadRow] = []
    interrupted = False
    end = began + duration_ns
    try:
        while time.monotonic_ns() < end and not all(r.poll() for r in runs):
            if stop_requested():
                interrupted = True
                break
            for r in runs:
                r.watch_state()
            if not table and time.monotonic_ns() >= began + duration_ns // 2:
                table = [row for r in runs if not r.poll() for row in kernel.thread_rows(r.pid)]
            time.sleep(min(0.05, max(0.0, (end - time.monotonic_ns()) / 1e9)))
    finally:
        monitor.stop()
    stopped = time.monotonic_ns()
    traced: tracing.TraceData | tracing.TraceUnavailable | None = tracer if isinstance(tracer, tracing.TraceUnavailable) else None
    tasks: dict[int, Task] = {}
    if isinstance(tracer, tracing.Tracer):
        tracer.window(began, stopped)
        traced = tracer.stop()
        tasks = {tid: Task(*task) for tid, task in tracing.named_tasks(traced).items()}  # while the processes live
    cell = CellResult(id=WATCH_CELL, spec_hash="-", status=Status.PASSED, started_at=started_at, duration_ns=stopped - began)
    failures: list[str] = []
    for run in runs:
        out = outcome(run.raw(began, stopped), began, stopped, interrupted, degradation)
        cell.programs.append(out.result)
        cell.threads.extend(t for _, t in out.threads)
        failures += out.failures
        cell.warnings += out.warnings
    cell.threads, cell.trace = apply(cell.threads, traced, tasks, began)
    cell.warnings += trace_warnings(cell.trace)
    ruled = sum(1 for t in cell.threads if t.rule is not None)
    if ruled:
        cell.warnings.append(
            f"--rule changed the settings of {ruled} thread{'s' if ruled != 1 else ''}; they keep them after the watch "
            "(the runner does not put back what they had)"
        )
    cell.thread_table = ps_rows(table)
    statuses = [Status.INTERRUPTED] if interrupted else [Status.ERROR] if failures else [Status.PASSED]
    if any(t.degraded for t in cell.threads):
        statuses.append(Status.ERROR)
        failures.append(
            "rules not applied as asked: " + "; ".join(f"{t.name}: {', '.join(t.degraded)}" for t in cell.threads if t.degraded)
        )
    cell.status = worst(statuses)
    cell.reason = "interrupted (Ctrl-C or SIGTERM): the figures cover the time until then" if interrupted else "; ".join(failures)
    from runner.run.machine import machine_info

    cell.machine = machine_info()
    names = sorted({r.spec.name for r in runs})
    return RunDocument(
        scenario=ScenarioInfo(name="watch-" + "-".join(names)[:80], description=f"runner watch of {', '.join(names)}"),
        started_at=started_at,
        finished_at=datetime.now(timezone.utc).isoformat(timespec="seconds"),
        status=cell.status.value,
        machine=cell.machine,
        permissions=PermissionsInfo(user=None),
        start_settings=start,
        cell_ids=[WATCH_CELL],
        matrix_cells=[WATCH_CELL],
        cells=[cell],
    )


def default_folder() -> str:
    """reports/watch/<UTC stamp>, as a run's folder is named."""
    return os.path.join("reports", "watch", datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ"))
