"""What the user's programs did, decided from what the shell read from outside: pure, no I/O.

A program's threads become threads of the results like the runner's own, named by their
own names (`ctl_loop`, not the process name), with the figures /proc gives every thread:
switches (totals and per second), faults, CPU time, migrations and the CPUs they were
found on.  What the runner asked for (the process's settings before exec, a rule's
settings) is compared with what the kernel reports, but only where the runner asked:
a thread the program created and no rule matched holds whatever the program gave it.
How the program ended decides whether the cell could be measured as written.
"""

from __future__ import annotations

import signal
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Optional

from runner import units
from runner.results.document import NOT_STARTED, FoldedRule, FoldedThreads, HistoryGap, ProgramResult, SettingsSnapshot, ThreadResult
from runner.results.threadfigures import Faults, Involuntary, ThreadFigures, Voluntary
from runner.run.child import signal_name
from runner.run.rawcell import ApplyErrors, OutputCount, RawProgram, RawProgramThread
from runner.run.rawcell import FoldedThreads as RawFolded
from runner.run.rawcell import HistoryGap as RawGap
from runner.scenario.limits import WATCHDOG_PRIORITY
from runner.scenario.model import ProgramSpec, SleepWork, Until
from runner.scenario.plan import PROGRAM_ORIGIN, PlannedThread, Settings, program_settings, rule_settings

DegradationFn = Callable[[Settings, Optional[Settings], ApplyErrors], list[str]]


@dataclass(frozen=True)
class ProgramOutcome:
    """One program's record, its threads (with what expectations match them by), and what went wrong."""

    result: ProgramResult
    threads: list[tuple[PlannedThread, ThreadResult]]
    failures: list[str]  # the cell could not be measured as written: an error
    warnings: list[str]
    # Threads folded beyond the cap of thread records, by name (as expectations match them) with how many: never checked.
    folded: list[tuple[PlannedThread, int]] = field(default_factory=list)
    folded_unnamed: int = 0  # folded threads whose names were not kept (beyond MAX_FOLDED_NAMES pairs): any name may be among them
    folded_cap: int = 0  # the thread records kept before threads that exit were folded


def _size(nbytes: int) -> str:
    """A size for a message in its largest unit: exact when whole (`64MiB`, `4B`), else to a tenth (`1.1GiB`)."""
    unit = next((u for u in ("TiB", "GiB", "MiB", "KiB") if nbytes >= units.BYTES_PER[u]), "")
    if not unit or nbytes % units.BYTES_PER[unit] == 0:
        return units.format_size(nbytes)
    return f"{nbytes / units.BYTES_PER[unit]:.1f}{unit}"


def output_warnings(who: str, stream: str, file: str, count: OutputCount, limit_key: str = "output_limit") -> list[str]:
    """What of `who`'s `stream` is not in its `file`, in words: beyond its limit, past a write that failed, or written
    after the cell's end by a process that outlived it; none when the file holds all it wrote.

    `who`: "program NAME" or "background command ARGV0"; `limit_key` names where its limit is set."""
    out = []
    if count.dropped:
        wrote = f"{who} wrote {_size(count.written)} to {stream}"
        if count.error:
            out.append(f"{wrote}; {file} took only the first {_size(count.kept)} ({count.error}), the rest was dropped")
        elif count.kept:
            out.append(
                f"{wrote}; the first {_size(count.kept)} are in {file}, the rest ({_size(count.dropped)}) was dropped "
                f"({limit_key}: {units.format_size(count.limit)})"
            )
        else:
            out.append(f"{wrote}; none of it was kept ({limit_key}: {units.format_size(count.limit)})")
    if count.held_open:
        out.append(
            f"{who}: a process it started still held its {stream} at the cell's end (it had no cgroup to stop it with); "
            "what that process wrote after was neither kept nor counted"
        )
    return out


def _per_second(count: int, ns: int) -> Optional[float]:
    return round(count * 1e9 / ns, 3) if ns > 0 else None


def _figures(t: RawProgramThread, complete: bool) -> ThreadFigures:
    """A program's thread's figures, from its counters over the window (to its last reading, for one that ended);
    `complete` False: its program was cut short (killed, crashed) or the cell interrupted."""
    c = t.counters
    if c is None:
        return ThreadFigures(
            callbacks=0,
            missed_releases=0,
            overruns=0,  # no callbacks: none missed or overran, as every runner has written for a program's thread
            involuntary=Involuntary(total=0),
            voluntary=Voluntary(total=0),
            faults=Faults(minor=0, major=0),
            complete=False,
        )
    return ThreadFigures(
        callbacks=0,
        missed_releases=0,
        overruns=0,
        involuntary=Involuntary(total=c.involuntary, per_second=_per_second(c.involuntary, t.measured_ns)),
        voluntary=Voluntary(total=c.voluntary, per_second=_per_second(c.voluntary, t.measured_ns)),
        faults=Faults(minor=c.minor_faults, major=c.major_faults),
        cpus_seen=t.cpus_seen,
        complete=complete,  # a thread gone before the end ended on its own: a thread exits only by itself, or with its process
        cpu_time_ns=c.cpu_time_ns,
        migrations=c.migrations,
    )


def _gap(gap: Optional[RawGap], since: Callable[[int], int]) -> Optional[HistoryGap]:
    """The changes a thread's history left out, their instants from the start gate."""
    if gap is None:
        return None
    first, last = since(gap.first_ns), since(gap.last_ns)
    return HistoryGap(count=gap.count, from_ns=first, to_ns=last, kept_first=gap.kept_first, kept_last=gap.kept_last)


def _folded(spec: ProgramSpec, folded: Optional[RawFolded], since: Callable[[int], int]) -> Optional[FoldedThreads]:
    """The threads a program's monitor counted together instead of keeping, their instants from the start gate."""
    if folded is None:
        return None
    c = folded.counters
    return FoldedThreads(
        cap=folded.cap,
        count=folded.count,
        measured=folded.measured,
        voluntary=c.voluntary,
        involuntary=c.involuntary,
        minor_faults=c.minor_faults,
        major_faults=c.major_faults,
        cpu_time_ns=c.cpu_time_ns,
        migrations=c.migrations,
        first_seen_ns=since(folded.first_seen_ns),
        last_gone_ns=since(folded.last_gone_ns),
        rules=[FoldedRule(rule=spec.threads[r.rule].match, applied=r.applied, not_as_asked=r.not_as_asked) for r in folded.rules],
    )


def _not_started(why: str) -> str:
    """A program's record when it never exec'd because the cell stopped first (`why`: the cell's reason, if known)."""
    return NOT_STARTED + (f" because {why}" if why else "")


def _role(t: RawProgramThread, pid: int) -> str:
    """What the thread is to the program, in words (the results' `work`)."""
    if t.index == 0:
        return "its main thread"
    return "a thread of the program" if t.pid in (0, pid) else f"a thread of process {t.pid}, which the program started"


def _ordinals(threads: tuple[RawProgramThread, ...]) -> dict[int, int]:
    """Each thread's index in the results: 0 for the main thread, then its rank among threads of its name.

    A thread's label (`talker/worker #2`) is its identity across runs; the order in which
    a program's threads happen to be created is not stable, their names are.
    """
    seen: dict[str, int] = {}
    out = {}  # by the thread's index of appearance: a TID the kernel reused names two threads
    for t in threads:
        if t.index == 0:
            out[t.index] = 0
            continue
        seen[t.comm] = seen.get(t.comm, 0) + 1
        out[t.index] = seen[t.comm]
    return out


def at_watchdog_priority(raw: RawProgram, t0: Optional[int], allowed: bool) -> tuple[list[str], list[str]]:
    """(failures, warnings): the program's threads the kernel showed at RT priority 99, the watchdog's own.

    The runner refuses priority 99 up front for what it starts (a program's sched, a rule) unless
    --allow-priority-99; a program can still raise a thread there itself (chrt, sched_setscheduler),
    which only the read-back shows, after the fact.  A thread that spins at 99 can keep the watchdog
    (also at 99, FIFO, never preempting an equal) off its CPU, so the cell's deadline no longer
    holds: the cell is an error unless the run allowed priority 99, and then a warning still says
    so.  A process the runner only watches is not its doing, and is not judged.
    """
    if raw.attached:
        return [], []
    seen = []
    for t in raw.threads:
        first = next((s for s in t.history if _at_99(s.settings)), None)
        if first is not None:
            when = f"{max(0, first.at_ns - t0) / 1e9:.2f}s into the cell" if t0 is not None else "before the cell started"
            seen.append(f"{t.comm} (tid {t.tid}, {first.settings.label()} {when})")
        elif t.applied is not None and _at_99(t.applied):  # the history left that change out: its last reading shows it
            seen.append(f"{t.comm} (tid {t.tid}, {t.applied.label()} when last read)")
    if not seen:
        return [], []
    named = ", ".join(seen[:3]) + (f" and {len(seen) - 3} more" if len(seen) > 3 else "")
    threads = f"thread{'s' if len(seen) != 1 else ''} {named}"
    if allowed:
        return [], [f"program {raw.spec.name} ran {threads} at RT priority 99, the runner watchdog's own (--allow-priority-99)"]
    return [
        f"program {raw.spec.name} raised {threads} to RT priority 99, the runner watchdog's own, which the runner refuses "
        "without --allow-priority-99: spinning there it could have kept the watchdog from stopping the cell; lower the "
        "program's priority to 98 or less, or pass --allow-priority-99"
    ], []


def _at_99(settings: Settings) -> bool:
    return settings.policy.is_realtime and settings.priority >= WATCHDOG_PRIORITY


def outcome(
    raw: RawProgram,
    t0: Optional[int],
    end_ns: int,
    interrupted: bool,
    degradation: DegradationFn,
    before_start: str = "",
    allow_priority_99: bool = False,
) -> ProgramOutcome:
    """A program's result, its threads and its failures; `start` is what it inherited from the runner.

    `degradation` says how settings fell short of a request, in words (evaluate.degradation).
    `before_start` is why the cell stopped before its start gate, when it did (another program
    not found, an interrupt): a program it left at its gate, or never launched, did not start,
    and its record says so and why; it adds no failure of its own, nor claims a duration or a signal.
    A thread at RT priority 99 fails it unless `allow_priority_99` (at_watchdog_priority).
    """
    spec, start = raw.spec, raw.start
    never_ran = not raw.attached and not raw.failure and raw.released_ns is None

    def since(ns: int) -> int:
        return ns - (t0 if t0 is not None else ns)

    main_wanted, others_wanted = program_settings(spec, start)
    failures: list[str] = []
    warnings: list[str] = []
    main = next((t for t in raw.threads if t.index == 0), None)
    main_first = main.history[0].settings if main and main.history else None
    # The runner applies a program's settings before exec, and the kernel's errno says whether each took: only
    # a refusal is a degradation.  What the program then sets itself (at once or later) is its own doing, in its history.
    refused = main is not None and not raw.attached and bool(raw.start_errors.failed())
    degraded = degradation(main_wanted, main_first, raw.start_errors) if refused else []
    at = (lambda ns: f"{max(0, ns - t0) / 1e9:.2f}s into the cell") if t0 is not None else (lambda ns: "before the cell started")
    exited_by_itself = raw.exited_ns is not None and not raw.stopped
    how = ""
    oom = bool(raw.oom_kills) and raw.exit_signal == signal.SIGKILL and raw.stopped != "SIGKILL"
    if spec.memory_max is not None and raw.memory_note:
        degraded.append(f"memory_max {units.format_size(spec.memory_max)} not applied: {raw.memory_note}")
    elif raw.memory_note and not raw.failure and not never_ran:
        warnings.append(
            f"program {spec.name} has no cgroup of its own ({raw.memory_note}): what it starts in a session of its own "
            "(setsid, a daemon) is neither measured nor stopped with it"
        )
    if oom:
        how = f"was killed by the OOM killer (SIGKILL): its cgroup reached its memory_max of {units.format_size(raw.memory_limit or 0)}"
    elif raw.exit_signal is not None:
        how = f"was killed by {signal_name(raw.exit_signal)}"
    elif raw.exit_code is not None:
        how = f"exited with code {raw.exit_code}"
    last = f"; its last output: {' | '.join(raw.tail)}" if raw.tail else "; it wrote nothing"
    if raw.failure or interrupted or never_ran:
        pass  # the shell could not start it (that is the cell's failure already), or the user stopped the cell
    elif t0 is None and not exited_by_itself:
        pass  # released, then stopped with the cell before its start (another program could not exec): the cell's failure says why
    elif raw.attached:
        if raw.exited_ns is not None:
            failures.append(f"process {spec.name} (pid {raw.pid}) exited {at(raw.exited_ns)}; its threads were measured until then")
    elif exited_by_itself and raw.exited_ns is not None:
        crashed = raw.exit_signal is not None or raw.exit_code != 0
        if spec.until is Until.END:
            failures.append(
                f"program {spec.name} {how} {at(raw.exited_ns)}; with until: end it must run the whole cell "
                f"(until: exit ends the cell when it exits){last}"
            )
        elif crashed:
            failures.append(f"program {spec.name} {how} {at(raw.exited_ns)}{last}")
    elif spec.until is Until.EXIT and raw.stopped:
        failures.append(
            f"program {spec.name} did not exit within the cell's {units.human_duration(end_ns - t0 if t0 else 0)} "
            f"and was stopped with {raw.stopped}{last}"
        )
    if raw.halted_ns is not None and not interrupted:
        what = "process" if raw.attached else "program"
        failures.append(
            f"{what} {spec.name} (pid {raw.pid}) was stopped (SIGSTOP or a debugger) {at(raw.halted_ns)}; "
            "its threads could not run while it was"
        )
    own = spec.sched is not None or spec.cpus is not None
    if own and main_first is not None and not refused and not raw.attached and not raw.failure:
        changed = degradation(main_wanted, main_first, ApplyErrors())
        if changed:
            warnings.append(
                f"program {spec.name} held other settings than the runner gave it before exec when first seen: {'; '.join(changed)} "
                "(the program, or the kernel, changed them; its history says when)"
            )
    high, allowed_high = at_watchdog_priority(raw, t0, allow_priority_99)
    failures += high
    warnings += allowed_high
    if raw.oom_kills and not oom:
        warnings.append(
            f"program {spec.name}: the OOM killer ended {raw.oom_kills} of its tasks at its memory_max of "
            f"{units.format_size(raw.memory_limit or 0)}"
        )
    if raw.stopped == "SIGKILL" and not raw.failure and not never_ran:
        warnings.append(f"program {spec.name} did not exit within {units.format_duration(spec.grace)} of SIGTERM and was killed (SIGKILL)")
    for stream, file, count in zip(("stdout", "stderr"), (raw.stdout, raw.stderr), raw.output):
        warnings += output_warnings(f"program {spec.name}", stream, file, count)
    result = ProgramResult(
        name=spec.name,
        argv=list(spec.command),
        path=raw.path,
        pid=raw.pid or None,
        started=raw.released_ns is not None and not raw.failure,
        failure=raw.failure or (_not_started(before_start) if never_ran else ""),
        requested=main_wanted,
        degraded=degraded,
        exit_code=raw.exit_code,
        exit_signal=signal_name(raw.exit_signal) if raw.exit_signal is not None else None,
        stopped=raw.stopped,
        ran_ns=(raw.exited_ns - raw.released_ns) if raw.exited_ns is not None and raw.released_ns is not None else None,
        stdout=raw.stdout,
        stderr=raw.stderr,
        output_limit=raw.output[0].limit if raw.output else None,
        stdout_bytes=raw.output[0].written if raw.output else None,
        stdout_dropped=raw.output[0].dropped if raw.output else None,
        stderr_bytes=raw.output[1].written if len(raw.output) > 1 else None,
        stderr_dropped=raw.output[1].dropped if len(raw.output) > 1 else None,
        tail=list(raw.tail),
        threads_seen_by=raw.seen_by,
        threads_seen_note=raw.seen_note,
        memory_max=raw.memory_limit,
        memory_peak=raw.memory_peak,
        oom_kills=raw.oom_kills,
        threads_folded=_folded(spec, raw.folded, since),
    )
    ordinal = _ordinals(raw.threads)
    killed = raw.exit_signal is not None and not raw.stopped  # a signal the runner did not send (a crash, the OOM killer): cut short
    threads = []
    for t in raw.threads:
        rule = spec.threads[t.rule] if t.rule is not None else None
        if rule is not None:  # the rule's settings, the main thread's too when a rule matched it
            wanted, errors, checked = rule_settings(spec, rule, start), t.rule_errors, True
        elif t.index == 0:
            wanted, errors, checked = main_wanted, raw.start_errors, refused
        else:
            wanted, errors, checked = others_wanted, ApplyErrors(), False  # only where the runner asked for something
        first = next((s.settings for s in t.history if s.why == ("rule" if rule is not None else "appeared")), None)
        thread_degraded = degradation(wanted, first, errors) if checked and first is not None else []
        planned = PlannedThread(spec.name, 0, ordinal[t.index], t.comm, rule.match if rule else t.comm, SleepWork(), wanted, PROGRAM_ORIGIN)
        threads.append(
            (
                planned,
                ThreadResult(
                    process=spec.name,
                    instance=0,
                    index=ordinal[t.index],
                    name=t.comm,
                    pid=t.pid or raw.pid,
                    tid=t.tid,
                    work=_role(t, raw.pid),
                    periodic=False,
                    requested=wanted,
                    applied=t.applied,
                    degraded=thread_degraded,
                    figures=_figures(t, not interrupted and not killed),
                    program=True,
                    rule=rule.match if rule else None,
                    rule_after_ns=(t.rule_ns - t.named_ns) if t.rule_ns is not None else None,
                    history=[SettingsSnapshot(at_ns=since(s.at_ns), comm=s.comm, settings=s.settings, why=s.why) for s in t.history],
                    history_not_kept=_gap(t.history_gap, since),
                ),
            )
        )
    folded: list[tuple[PlannedThread, int]] = []
    for group in raw.folded.names if raw.folded is not None else ():
        rule = spec.threads[group.rule] if group.rule is not None else None
        wanted = rule_settings(spec, rule, start) if rule is not None else others_wanted
        name = rule.match if rule is not None else group.comm
        folded.append((PlannedThread(spec.name, 0, 0, group.comm, name, SleepWork(), wanted, PROGRAM_ORIGIN), group.count))
    folded_rules = {r.rule for r in raw.folded.rules} if raw.folded is not None else set()
    for i, rule in enumerate(spec.threads):
        if not raw.failure and not never_ran and not any(t.rule == i for t in raw.threads) and i not in folded_rules:
            seen = sorted({t.comm for t in raw.threads})
            warnings.append(f"program {spec.name}: no thread matched the rule {rule.match!r}; its threads: {', '.join(seen) or 'none'}")
    unnamed, cap = (raw.folded.names_not_kept, raw.folded.cap) if raw.folded is not None else (0, 0)
    return ProgramOutcome(result, threads, failures, warnings, folded, unnamed, cap)
