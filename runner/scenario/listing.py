"""`runner FILE --list`: each cell with the settings every thread should end up with.

Pure rendering; the caller supplies the starting settings (the runner's own) and
the online CPUs so the listing says what this machine would do.
"""

from __future__ import annotations

from tabulate import tabulate

from runner import units
from runner.scenario.loader import LoadedScenario, ResolvedCell, expectations_for
from runner.scenario.model import BurnClock, HogKind, PeriodicWork, ProcessSpec, Scenario, SleepWork, SpinWork, Work
from runner.scenario.plan import Settings, plan_process


def describe_work(work: Work) -> str:
    """`periodic 100ms, burn 40ms cpu` / `spin` / `sleep`."""
    if isinstance(work, PeriodicWork):
        text = f"periodic {units.format_duration(work.period)}"
        if work.burn:
            clock = "cpu" if work.burn_clock is BurnClock.THREAD_CPU else "wall"
            text += f", burn {units.format_duration(work.burn)} {clock}"
        if work.alloc:
            text += f", alloc {units.format_size(work.alloc)}"
        if work.offset:
            text += f", offset {units.format_duration(work.offset)}"
        return text
    if isinstance(work, SpinWork):
        return "spin"
    assert isinstance(work, SleepWork)
    return "sleep"


def describe_memory(proc: ProcessSpec) -> str:
    mem = proc.memory
    parts = ["locked" if mem.lock else "not locked"]
    if mem.prealloc:
        parts.append(f"prealloc {units.format_size(mem.prealloc)}")
    if mem.stack_size is not None:
        parts.append(f"stack {units.format_size(mem.stack_size)}")
    return ", ".join(parts)


def render_cell(cell: ResolvedCell, start: Settings, online: tuple[int, ...]) -> str:
    """One cell: background, processes with per-thread settings, expectations."""
    sc: Scenario = cell.scenario
    lines = [f"cell {cell.id}  (spec {cell.spec_hash}, duration {units.format_duration(sc.duration)})"]
    for hog in sc.background.hogs:
        sched = hog.sched.label() if hog.sched else "inherited"
        where = units.format_cpus(hog.cpus) if hog.cpus else "any CPU"
        noun = {(True, True): "process", (True, False): "processes", (False, True): "thread", (False, False): "threads"}[
            (hog.kind is HogKind.PROCESS, hog.count == 1)
        ]
        lines.append(f"  background: {hog.count} busy {noun} {hog.name!r}, {sched}, {where}")
    for cmd in sc.background.commands:
        lines.append(f"  background: command {cmd.argv!r}")
    for proc in sc.processes:
        copies = f", {proc.instances} instances" if proc.instances > 1 else ""
        reset = ", reset-on-fork" if proc.reset_on_fork else ""
        apply = proc.main.apply.value.replace("_", " ")
        lines.append(f"  process {proc.name}{copies}{reset}; memory {describe_memory(proc)}; main thread settings {apply}")
        rows = []
        for t in plan_process(proc, start):
            rows.append(
                [
                    t.index if t.index else "main",
                    t.name,
                    t.settings.label(),
                    t.settings.nice,
                    t.settings.cpus_label(online),
                    t.origin,
                    describe_work(t.work),
                ]
            )
        table = tabulate(rows, headers=["#", "THREAD", "POLICY", "NICE", "CPUS", "SETTINGS", "WORK"], tablefmt="plain")
        lines.extend("    " + row for row in table.splitlines())
    for i in expectations_for(sc, cell):
        exp = sc.expect[i]
        lines.append(f"  expect {exp.thread}: {exp.metric.value} {exp.describe_limit()}")
    return "\n".join(lines)


def render(loaded: LoadedScenario, start: Settings, online: tuple[int, ...]) -> str:
    """The whole listing of a scenario file."""
    count = len(loaded.cells)
    head = [f"{loaded.name}: {count} cell{'s' if count != 1 else ''} ({loaded.path})"]
    if loaded.description:
        head.append("  " + loaded.description)
    return "\n\n".join(["\n".join(head)] + [render_cell(c, start, online) for c in loaded.cells]) + "\n"
