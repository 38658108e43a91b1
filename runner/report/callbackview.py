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
_TIMING_WORDS = (
    "latency: from a timer's release to the start of the callback that served it; age: from a message's source timestamp "
    "to the start of the callback that took it; chain: from the release of the timer callback whose message reached it to its end"
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


def _trace_words(i: CallbackInstance, thread: ThreadResult | None) -> str:
    """What the trace says of an instance's thread meanwhile: the preempted runs it kept that overlap it; "" for nothing."""
    if thread is None or thread.figures.preemptions is None:
        return ""
    runs = [r for r in thread.preempted_runs if r.at_ns < i.at_ns + i.wall_ns and i.at_ns < r.at_ns + r.wall_ns]
    if runs:
        return "; ".join(_run(r) for r in runs)
    if thread.preempted_by and i.involuntary:  # the trace kept only the thread's most preempted runs
        return "its thread, over the cell: preempted " + ", ".join(_preemptor(p) for p in thread.preempted_by)
    return ""


def slowest_table(cell: CellResult, callbacks: list[CallbackResult]) -> Table | None:
    """The slowest instances of each callback an involuntary switch ever hit, with who preempted its thread meanwhile
    (the scheduler trace's preempted runs of that thread overlapping the instance); None when none was hit."""
    by_tid = {t.tid: t for t in cell.threads if t.program}
    hit = [c for c in callbacks if c.slowest and c.figures.involuntary.per_callback_max]
    shown = [(c, i) for c in hit for i in c.slowest[:SLOWEST_SHOWN]]
    if not shown:
        return None
    sc = fg.scale(fg.Unit.NS, [v for _, i in shown for v in (i.wall_ns, i.latency_ns)])
    rows = [
        [
            md_code(c.name, in_table=True),
            f"{i.at_ns / 1e9:.3f}",
            str(i.tid),
            sc.number(i.wall_ns),
            sc.number(i.latency_ns),
            fmt_int(i.involuntary),
            md_text(_trace_words(i, by_tid.get(i.tid)) or "–", in_table=True),
        ]
        for c, i in shown
    ]
    headers = ["Callback", "At (s)", "Thread", sc.header("Duration"), sc.header("After its release"), "Involuntary", "The trace"]
    return Table(headers, rows, [LEFT, RIGHT, RIGHT, RIGHT, RIGHT, RIGHT, LEFT])


def notes_table(notes: list[str], callbacks: list[CallbackResult]) -> Table | None:
    """What the capture said of the program, and of each callback, in words; None when it said nothing."""
    rows = [["the program", md_text(n, in_table=True)] for n in notes]
    rows += [[md_code(c.name, in_table=True), md_text(n, in_table=True)] for c in callbacks for n in c.notes]
    return Table(["Of", "What the capture says"], rows, [LEFT, LEFT]) if rows else None


def callback_tables(cell: CellResult) -> list[tuple[Markdown, Table]]:
    """The captioned tables of a cell's ROS 2 callbacks, per program whose capture ran: what each callback is, its
    switches and faults, its timing, what the capture said in words, its slowest instances joined with the trace."""
    out: list[tuple[Markdown, Table]] = []
    for prog in cell.programs:
        if prog.ros is None:
            continue
        name = md_text(prog.name)
        mine = [c for c in cell.callbacks if c.program == prog.name]
        if mine:
            out += [
                (Markdown(f"ROS 2 callbacks of {name}, measured inside it"), what_table(mine)),
                (Markdown(f"Involuntary switches and page faults per callback of {name} (getrusage around each)"), switches_table(mine)),
                (Markdown(f"Timing of the callbacks of {name} ({_TIMING_WORDS})"), timing_table(mine)),
            ]
        notes = notes_table(prog.ros.notes, mine)
        if notes is not None:
            out.append((Markdown(f"What the capture of {name}'s callbacks says"), notes))
        slowest = slowest_table(cell, mine)
        if slowest is not None:
            out.append((Markdown(f"The slowest callbacks of {name}, and who preempted their thread meanwhile (scheduler trace)"), slowest))
    return out
