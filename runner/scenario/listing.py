"""`runner FILE --list`: each cell with the settings every thread should end up with.

Pure rendering; the caller supplies the starting settings (the runner's own) and
the online CPUs so the listing says what this machine would do.
"""

from __future__ import annotations

import shlex
from typing import Any, Optional

from runner import units
from runner.scenario.loader import LoadedScenario, ResolvedCell
from runner.scenario.matching import expectations_for
from runner.scenario.model import (
    HogKind,
    PeriodicWork,
    Pin,
    ProcessSpec,
    ProgramSpec,
    Scenario,
    ThreadSpec,
    Until,
)
from runner.scenario.plan import Settings, plan_process, program_settings, rule_settings
from runner.scenario.worktext import describe_work


def _plain(rows: list[list[Any]], headers: Optional[list[str]] = None) -> str:
    """Rows as tabulate's plain table; tabulate is imported here, so `runner validate` does not pay for it (with wcwidth, about 50 ms)."""
    from tabulate import tabulate

    return tabulate(rows, headers=headers or (), tablefmt="plain")


def describe_memory(proc: ProcessSpec) -> str:
    mem = proc.memory
    parts = ["locked" if mem.lock else "not locked"]
    if mem.prealloc:
        parts.append(f"prealloc {units.format_size(mem.prealloc)}")
    if mem.stack_size is not None:
        parts.append(f"stack {units.format_size(mem.stack_size)}")
    return ", ".join(parts)


def describe_spread(spec: ThreadSpec) -> str:
    """How the threads of a spec differ, in words, e.g. `cyclic: 2 threads (count: cpus, one per CPU: the 2 CPUs
    the runner may use (0-1)), each pinned to its own CPU, priorities fifo:80 down to fifo:79`."""
    text = f"{spec.name}: {spec.count} thread{'s' if spec.count != 1 else ''}{spec.count_source()}"
    members = spec.members()
    first, last = members[0], members[-1]
    if spec.pin is Pin.EACH:
        text += ", each pinned to its own CPU and named by it"
    if spec.priospread and first.sched is not None and last.sched is not None:
        text += f", priorities {first.sched.label()} down to {last.sched.label()} (priospread)"
    if spec.distance and isinstance(first.work, PeriodicWork) and isinstance(last.work, PeriodicWork):
        text += (
            f", periods {units.format_duration(first.work.period)} to {units.format_duration(last.work.period)}"
            f" (distance {units.format_duration(spec.distance)})"
        )
    return text


def spread_lines(proc: ProcessSpec) -> list[str]:
    """Each spec of `proc` whose threads differ or depend on the machine: its description, then thread by thread."""
    out: list[str] = []
    for spec in proc.threads:
        if not spec.varies:
            continue
        out.append(f"{proc.name}/{describe_spread(spec)}")
        rows = [
            [
                m.name,
                ("CPU " if m.cpus is not None and len(m.cpus) == 1 else "CPUs ") + (units.format_cpus(m.cpus) if m.cpus else "as created"),
                m.sched.label() if m.sched is not None else "sched as created",
                describe_work(m.work),
            ]
            for m in spec.members()
        ]
        out.extend("  " + row for row in _plain(rows).splitlines())
    return out


def expansion(loaded: LoadedScenario) -> list[str]:
    """What `runner validate` shows below `ok`: thread specs that spread over CPUs, priorities or periods, resolved
    on this machine (`count: cpus` is its CPUs), thread by thread; said once when every cell resolves alike."""
    blocks: dict[str, list[str]] = {}
    for cell in loaded.cells:
        lines = [line for proc in cell.scenario.workers for line in spread_lines(proc)]
        if lines:
            blocks.setdefault("\n".join(lines), []).append(cell.id)
    out: list[str] = []
    for text, ids in blocks.items():
        if len(blocks) > 1 or len(ids) < len(loaded.cells):
            named = ", ".join(ids[:3]) + (f" and {len(ids) - 3} more" if len(ids) > 3 else "")
            out.append(f"in cell{'s' if len(ids) != 1 else ''} {named}:")
        out.extend(text.splitlines())
    return out


def render_cell(cell: ResolvedCell, start: Settings, online: tuple[int, ...], duration_ns: Optional[int] = None) -> str:
    """One cell: background, processes with per-thread settings, expectations; `duration_ns`: --duration, if given."""
    sc: Scenario = cell.scenario
    lines = [f"cell {cell.id}  (spec {cell.spec_hash}, duration {units.format_duration(duration_ns or sc.duration)})"]
    for hog in sc.background.hogs:
        sched = hog.sched.label() if hog.sched else "inherited"
        where = units.format_cpus(hog.cpus) if hog.cpus else "any CPU"
        noun = {(True, True): "process", (True, False): "processes", (False, True): "thread", (False, False): "threads"}[
            (hog.kind is HogKind.PROCESS, hog.count == 1)
        ]
        lines.append(f"  background: {hog.count} busy {noun} {hog.name!r}, {sched}, {where}")
    for cmd in sc.background.commands:
        lines.append(f"  background: command {cmd.argv!r}")
    for prog in sc.programs:
        lines.extend(_program_lines(prog, start, online))
    for proc in sc.workers:
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
                    f"spawned, {t.origin}" if t.spawned else t.origin,
                    describe_work(t.work),
                ]
            )
        table = _plain(rows, ["#", "THREAD", "POLICY", "NICE", "CPUS", "SETTINGS", "WORK"])
        lines.extend("    " + row for row in table.splitlines())
        lines.extend(f"    {describe_spread(spec)}" for spec in proc.threads if spec.varies)
    for i in expectations_for(sc, cell.matrix):
        exp = sc.expect[i]
        lines.append(f"  expect {exp.target}: {exp.metric.value} {exp.describe_limit()}")
    return "\n".join(lines)


def _program_lines(prog: ProgramSpec, start: Settings, online: tuple[int, ...]) -> list[str]:
    """A program: its command, the settings it is started with, and its thread rules."""
    main, others = program_settings(prog, start)
    until = "runs until the cell ends" if prog.until is Until.END else "the cell ends when it exits"
    reset = ", reset-on-fork" if prog.reset_on_fork else ""
    lines = [f"  program {prog.name}: {shlex.join(prog.command)}; {until}{reset}"]
    rows = [["main", "(its main thread)", main.label(), main.nice, main.cpus_label(online), "before exec"]]
    if others != main:
        rows.append(["", "(threads it creates)", others.label(), others.nice, others.cpus_label(online), "reset on fork"])
    for rule in prog.threads:
        wanted = rule_settings(prog, rule, start)
        rows.append(["rule", rule.match, wanted.label(), wanted.nice, wanted.cpus_label(online), "when it appears"])
    table = _plain(rows, ["", "THREAD", "POLICY", "NICE", "CPUS", "APPLIED"])
    return lines + ["    " + row for row in table.splitlines()]


def render(
    loaded: LoadedScenario,
    start: Settings,
    online: tuple[int, ...],
    cells: Optional[list[ResolvedCell]] = None,
    duration_ns: Optional[int] = None,
) -> str:
    """The listing of a scenario file: its cells (`cells`: those a run would run, --cell and --shard applied)."""
    shown = loaded.cells if cells is None else cells
    count = len(shown)
    of = f" of {len(loaded.cells)}" if count != len(loaded.cells) else ""
    head = [f"{loaded.name}: {count}{of} cell{'s' if len(loaded.cells) != 1 else ''} ({loaded.path})"]
    if loaded.description:
        head.append("  " + loaded.description)
    return "\n\n".join(["\n".join(head)] + [render_cell(c, start, online, duration_ns) for c in shown]) + "\n"
