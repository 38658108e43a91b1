"""The ROS 2 callbacks of a cell's programs in the report (issue 38): per program a table of what each callback is and
how often it ran, one of its timing, what the capture said in words, and its slowest instances joined with the trace.  Pure.

Latency here is a timer callback's: from its release (the timer's grid) to the start of the
callback that served it, the releases it skipped included; a message's age runs from its
source timestamp to the start of the callback that took it.  The slowest instances are
joined with the scheduler trace by thread and time: the preempted runs the trace kept for
that thread (runner/run/traced.py) that overlap the instance say who held the CPU from it.
"""

from __future__ import annotations

from runner import figures as fg
from runner import units
from runner.report.fmt import LEFT, RIGHT, Markdown, fmt_int, fmt_mean, md_code, md_text
from runner.report.tables import Table, _preemptor, _run
from runner.results.document import CallbackInstance, CallbackResult, CellResult, ThreadResult

THREADS_SHOWN = 3
SLOWEST_SHOWN = 3
_INTRO = (
    "ROS 2 callbacks of {program}, measured inside it (latency: from a timer's release to the start of the callback that "
    "served it; age: from a message's source timestamp to the start of the callback that took it):"
)


def _what(c: CallbackResult) -> str:
    """`timer 100ms`, `subscription /chatter`, `service /add_two_ints`, `callback`: what the callback is."""
    if c.kind == "timer":
        clock = f", {c.clock} clock" if c.clock not in ("", "steady", "unknown") else ""
        return f"timer {units.format_duration(c.period_ns)}{clock}" if c.period_ns else "timer"
    return f"{c.kind} {c.topic}".strip()


def _threads(c: CallbackResult) -> str:
    shown = [f"{t.comm} ({t.tid})" for t in c.threads[:THREADS_SHOWN]]
    more = len(c.threads) - THREADS_SHOWN
    return ", ".join(shown) + (f" and {more} more" if more > 0 else "")


def what_table(callbacks: list[CallbackResult]) -> Table:
    """Per callback: what it is, where it ran, how often, and whether it kept up with its timer."""
    rows = []
    for c in callbacks:
        f = c.figures
        timer = c.kind == "timer" and f.releases > 0
        rows.append(
            [
                md_code(c.name, in_table=True),
                md_text(_what(c), in_table=True),
                md_text(_threads(c), in_table=True),
                fmt_int(f.callbacks),
                (fmt_int(f.missed_releases) + (" ⚠️" if f.missed_releases else "")) if timer else "–",
                (fmt_int(f.overruns) + (" ⚠️" if f.overruns else "")) if timer else "–",
            ]
        )
    return Table(["Callback", "What", "Threads", "Count", "Missed", "Overruns"], rows, [LEFT, LEFT, LEFT, RIGHT, RIGHT, RIGHT])


def switches_table(callbacks: list[CallbackResult]) -> Table:
    """Per callback, the seed's figure: involuntary switches during each instance (getrusage around it), and its page faults."""
    rows = [
        [
            md_code(c.name, in_table=True),
            fmt_mean(c.figures.involuntary.per_callback_mean),
            fmt_int(c.figures.involuntary.per_callback_max),
            fmt_int(c.figures.involuntary.callbacks_with_any),
            fmt_int(c.figures.faults.minor_after_first),
            fmt_int(c.figures.faults.major),
        ]
        for c in callbacks
    ]
    headers = ["Callback", "Involuntary / callback (mean)", "(max)", "Callbacks preempted", "Minor faults after the 1st", "Major faults"]
    return Table(headers, rows, [LEFT] + [RIGHT] * 5)


_TIMING = (
    ("Latency p50", "latency.p50"),
    ("p99", "latency.p99"),
    ("max", "latency.max"),
    ("Duration p99", None),
    ("Age p99", "message_age.p99"),
    ("Chain p99", "chain.p99"),
)


def _timing(c: CallbackResult, name: str | None) -> int | float | None:
    if name is None:
        wall = c.figures.callback_wall_ns
        return wall.p99 if wall is not None else None
    return fg.value(c.figures, fg.figure(name))


def timing_table(callbacks: list[CallbackResult]) -> Table:
    """Per callback, in one unit: its latency from the release, its duration, the age of the messages it took, its chain."""
    sc = fg.scale(fg.Unit.NS, (_timing(c, name) for c in callbacks for _, name in _TIMING))
    rows = [[md_code(c.name, in_table=True), *(sc.number(_timing(c, name)) for _, name in _TIMING)] for c in callbacks]
    return Table(["Callback", *(sc.header(words) for words, _ in _TIMING)], rows, [LEFT] + [RIGHT] * len(_TIMING))


def _joined(i: CallbackInstance, thread: ThreadResult | None) -> str:
    """An instance with what the trace says of its thread then: the preempted runs it kept that overlap it."""
    late = f", {units.human_duration(i.latency_ns)} after its release" if i.latency_ns is not None else ""
    switches = f"{i.involuntary:,} involuntary switch{'es' if i.involuntary != 1 else ''}"
    line = f"at {i.at_ns / 1e9:.3f} s on {i.tid}: {units.human_duration(i.wall_ns)}{late}, {switches}"
    if thread is None or thread.figures.preemptions is None:
        return line
    runs = [r for r in thread.preempted_runs if r.at_ns < i.at_ns + i.wall_ns and i.at_ns < r.at_ns + r.wall_ns]
    if runs:
        return line + "; the trace: " + "; ".join(_run(r) for r in runs)
    if thread.preempted_by and i.involuntary:  # the trace kept only the thread's most preempted runs
        return line + "; its thread, over the cell: preempted " + ", ".join(_preemptor(p) for p in thread.preempted_by)
    return line


def slowest_lines(cell: CellResult, callbacks: list[CallbackResult]) -> list[Markdown]:
    """`name`: its slowest instances, each with who preempted its thread meanwhile when the trace followed that thread."""
    by_tid = {t.tid: t for t in cell.threads if t.program}
    out = []
    for c in callbacks:
        if not c.slowest or not c.figures.involuntary.per_callback_max:
            continue  # never switched out involuntarily: nobody preempted it
        shown = "; ".join(_joined(i, by_tid.get(i.tid)) for i in c.slowest[:SLOWEST_SHOWN])
        out.append(Markdown(f"{md_code(c.name)}: slowest {md_text(shown)}"))
    return out


def callbacks_block(cell: CellResult) -> Markdown | None:
    """The callbacks section of a cell: per program whose capture ran, its tables, its words, its slowest callbacks."""
    parts: list[str] = []
    for prog in cell.programs:
        if prog.ros is None:
            continue
        mine = [c for c in cell.callbacks if c.program == prog.name]
        parts.append(_INTRO.format(program=md_text(prog.name)))
        if mine:
            parts += [what_table(mine).render(), switches_table(mine).render(), timing_table(mine).render()]
        words = [md_text(n) for n in prog.ros.notes] + [Markdown(f"{md_code(c.name)}: {md_text(n)}") for c in mine for n in c.notes]
        words += slowest_lines(cell, mine)
        if words:
            parts.append("\n".join(f"- {w}" for w in words))
    return Markdown("\n\n".join(parts)) if parts else None
