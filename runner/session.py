"""Run a scenario: permissions, output folder, one cell after another, results, report, exit code.

Cells run one at a time (they compete for the CPUs), each repeat a cell of its
own, with a settle pause between them.  Each finished cell is journaled at once
(`runner.results.journal`) and results.json rewritten atomically as that allows,
so `--resume DIR` can finish an interrupted run and a SIGKILL loses at most the
cell in flight.
"""

from __future__ import annotations

import argparse
import errno
import fnmatch
import os
import random
import signal
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from typing import Any, Optional

from runner import outdir, units
from runner.collector import collector_paused
from runner.errors import ExitCode, OutputError, Problem, RunnerError, ScenarioError, UsageError, from_os_error, shorten
from runner.report.cellview import render_cell
from runner.report.compare import Threshold, check_common, check_comparable, thresholds_for
from runner.results.document import CellResult, MachineInfo, Plan, RunDocument, ScenarioInfo, Status, worst
from runner.results.files import cell_dir, results_file, slug
from runner.results.journal import ResultsStore
from runner.results.read import load
from runner.results.samplesfile import SamplesWriter
from runner.run.backend import Backend, CellOptions
from runner.run.dmalatency import MAX_US as MAX_DMA_LATENCY_US
from runner.run.evaluate import evaluate, unrun, with_write_error
from runner.run.preflight import Permissions
from runner.run.samples import NO_HOLDERS, Sample
from runner.run.samples import rows as sample_rows
from runner.runorder import Shard, Unit, plan_units
from runner.safefs import make_folders
from runner.scenario.loader import LoadedScenario, ResolvedCell, expect_hash, spec_json
from runner.scenario.model import MAX_REPEAT, MAX_RUN, MAX_SETTLE, MIN_RUN, SamplesMode
from runner.scenario.plan import Settings
from runner.scenario.program import never_released
from runner.terminal import Progress, note, say, warn

DEFAULT_SETTLE_NS = 500_000_000


@dataclass
class RunOptions:
    duration_ns: Optional[int]
    cells: list[str]
    out: Optional[str]
    follow: bool
    allow_degraded: bool
    allow_priority_99: bool
    quiet: bool
    command: list[str]
    repeat: int = 1
    shuffle_seed: Optional[int] = None
    shuffle_drawn: bool = False  # --shuffle without a seed: the run drew it, so it prints it for the order to be run again
    settle_ns: int = DEFAULT_SETTLE_NS
    shard: Optional[Shard] = None
    resume: Optional[str] = None
    baseline: Optional[str] = None
    history: Optional[str] = None  # --history FILE|URL: judge against the past nights there, then add this one
    thresholds: list[Threshold] = field(default_factory=list)
    report: bool = True
    plots: bool = True
    live: bool = True  # a live progress line (a terminal, not CI)
    dma_latency_us: Optional[int] = 0  # /dev/cpu_dma_latency held at this while cells run; None: left alone
    junit: Optional[str] = None  # --junit FILE: the run as JUnit XML, for CI test reporters
    trace: bool = True  # trace the scheduler (tracefs) while cells run, where the kernel lets the runner
    lava: bool = False  # --lava: after the report, each cell as a LAVA test set (runner/report/lava.py)
    resume_options: dict[str, Any] = field(default_factory=dict)  # with --resume: the run-shaping options given, as _shaping_values

    @classmethod
    def from_namespace(cls, ns: argparse.Namespace, env: dict[str, str]) -> RunOptions:
        duration = parse_duration(ns.duration, "--duration", MIN_RUN, MAX_RUN) if ns.duration else None
        settle = parse_duration(ns.settle, "--settle", 0, MAX_SETTLE) if ns.settle is not None else DEFAULT_SETTLE_NS
        repeat = 1 if ns.repeat is None else parse_number(ns.repeat, "runner: --repeat", 1, MAX_REPEAT)
        seed = None
        if ns.shuffle == "random":
            seed = random.SystemRandom().randrange(1 << 31)
        elif ns.shuffle is not None:
            seed = parse_number(ns.shuffle, "runner: --shuffle", -(1 << 63), (1 << 63) - 1)
        if ns.resume and ns.out:
            raise UsageError("runner: --resume DIR writes into DIR; leave out --out")
        in_ci = env.get("CI", "") not in ("", "0", "false")
        dma_latency = None if ns.no_dma_latency else _dma_latency(ns.dma_latency)
        shard = Shard.parse(ns.shard) if ns.shard else None
        given = {
            "--duration": duration,
            "--cell": ns.cell,
            "--repeat": repeat,
            "--shuffle": "random" if ns.shuffle == "random" else seed,  # a random seed is no recorded one
            "--settle": settle,
            "--shard": str(shard) if shard else None,
            "--dma-latency": dma_latency,
            "--no-dma-latency": dma_latency,
            "--no-trace": not ns.no_trace,
        }
        values = _shaping_values(given)
        shaping = {option: values[option] for option in _run_shaping(ns)} if ns.resume else {}
        return cls(
            duration,
            ns.cell,
            ns.out,
            ns.follow,
            ns.allow_degraded,
            ns.allow_priority_99,
            ns.quiet,
            ["runner"] + sys.argv[1:],
            repeat=repeat,
            shuffle_seed=seed,
            shuffle_drawn=ns.shuffle == "random",
            settle_ns=settle,
            shard=shard,
            resume=ns.resume,
            baseline=ns.baseline,
            history=ns.history,
            thresholds=thresholds_for(ns.threshold, ns.baseline, ns.history, has_history=True),
            report=not ns.no_report,
            plots=not ns.no_plots,
            live=not (ns.quiet or in_ci),
            dma_latency_us=dma_latency,
            junit=outdir.writable_file(ns.junit, "--junit") if ns.junit else None,
            trace=not ns.no_trace,
            lava=ns.lava,
            resume_options=shaping,
        )


def _run_shaping(ns: argparse.Namespace) -> list[str]:
    """The options given that decide how cells run, which a resumed run takes from its folder instead."""
    given = {
        "--duration": ns.duration,
        "--cell": ns.cell,
        "--repeat": ns.repeat,
        "--shuffle": ns.shuffle,
        "--settle": ns.settle,
        "--shard": ns.shard,
        "--dma-latency": ns.dma_latency,
        "--no-dma-latency": ns.no_dma_latency,
        "--no-trace": ns.no_trace,
    }
    return [option for option, value in given.items() if value not in (None, [], False)]


def parse_duration(text: str, option: str, minimum: int, maximum: int) -> int:
    """A duration option in ns, held to the same range a scenario file is (a cell runs 100ms to 24h)."""
    try:
        value = units.parse_duration(text)
    except units.UnitError as exc:
        raise UsageError(f"runner: {option}: {exc}") from None
    if not minimum <= value <= maximum:
        raise UsageError(
            f"runner: {option} {text} is out of range; expected {units.format_duration(minimum)} to {units.format_duration(maximum)}"
        )
    return value


def parse_number(text: str, option: str, low: int, high: int) -> int:
    """A whole-number option (ASCII digits; `option` as said: `runner: --repeat`), held to its range; a UsageError otherwise."""
    try:
        return units.parse_whole(text, low, high, f"{option} {shorten(text.strip(), 40)}")
    except units.UnitError as exc:
        raise UsageError(str(exc)) from None


def _dma_latency(text: Optional[str]) -> int:
    """--dma-latency US: whole microseconds the CPU latency QoS accepts (0, the default, keeps CPUs out of deep idle)."""
    if text is None:
        return 0
    digits = text.strip().removesuffix("us")
    try:
        return units.parse_whole(digits, 0, MAX_DMA_LATENCY_US)
    except units.UnitError:
        raise UsageError(
            f"runner: --dma-latency {shorten(text)}: expected whole microseconds from 0 to {MAX_DMA_LATENCY_US:,}, e.g. 0 or 10us; "
            "--no-dma-latency leaves /dev/cpu_dma_latency alone"
        ) from None


def exit_code(statuses: list[Status], regressions: int = 0) -> ExitCode:
    """The one place an outcome becomes an exit code (docs/commands.md, 'Exit codes'): a run's or a merge's cells,
    and the regressions of any comparison (`compare` passes `Comparison.statuses()`: the new run's cells
    that could not run, and the run itself when it is incomplete).

    Errors are the other way out: each error class carries its code, and cli._guarded maps them.
    """
    status = worst(statuses)
    code = {
        Status.PASSED: ExitCode.OK,
        Status.DEGRADED: ExitCode.OK,
        Status.FAILED: ExitCode.EXPECTATION_FAILED,
        Status.ERROR: ExitCode.RUN_ERROR,
        Status.INTERRUPTED: ExitCode.INTERRUPTED,
    }[status]
    if regressions and code == ExitCode.OK:
        return ExitCode.EXPECTATION_FAILED
    return code


class StopSignals:
    """Ctrl-C, SIGTERM and SIGHUP as a request to stop, honoured at the run's safe points, never mid-write.

    The handler only records the request: the cell loop and the cell's supervision poll it and
    stop there, so results.json and the report are always written.  A second or third signal
    while the runner is already stopping changes nothing (it says so once), so an impatient
    Ctrl-C can no longer cut the report short or leave the run without results.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)  # SIGHUP: the terminal or the ssh session went away

    def __init__(self) -> None:
        self.received: Optional[int] = None
        self.told = False
        self.previous: dict[int, Any] = {}
        self.late_words = ""  # said at the first signal once no cell is left to stop (the cell loop says its own)

    def __enter__(self) -> StopSignals:
        for sig in self.SIGNALS:
            if signal.getsignal(sig) is signal.SIG_IGN:
                continue  # ignored on entry, as nohup does for SIGHUP: the caller's choice stands
            self.previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self.previous.items():
            signal.signal(sig, handler)

    def _handle(self, signum: int, frame: Any) -> None:
        first = self.received is None
        if first:
            self.received = signum
        if (first and self.late_words) or (not first and not self.told):
            self.told = True
            words = self.late_words if first else "runner: already stopping; writing the results and the report"
            try:
                os.write(2, words.encode() + b"\n")
            except OSError:
                pass

    def requested(self) -> bool:
        return self.received is not None


def select_cells(loaded: LoadedScenario, options: RunOptions) -> list[ResolvedCell]:
    """The cells this run owns: its shard of the matrix, then those matching --cell."""
    ids = [c.id for c in loaded.cells]
    if options.shard:
        ids = options.shard.take(ids)

    def wanted(cell_id: str) -> bool:
        return not options.cells or any(fnmatch.fnmatchcase(cell_id, g) for g in options.cells)

    chosen = [c for c in loaded.cells if c.id in ids and wanted(c.id)]
    if not chosen and options.cells:
        elsewhere = [(n, c.id) for n, c in enumerate(loaded.cells) if wanted(c.id)]
        if options.shard and elsewhere:  # a real cell, in another CI job's part of the matrix
            shard = options.shard
            where = ", ".join(f"{cell_id} is in shard {n % shard.count + 1}/{shard.count}" for n, cell_id in elsewhere)
            held = f"holds: {', '.join(ids)}" if ids else f"holds none of the scenario's {len(loaded.cells)} cells"
            raise UsageError(f"runner: no cell of shard {shard} matches {', '.join(options.cells)} ({where}); shard {shard} {held}")
        raise UsageError(f"runner: no cell matches {', '.join(options.cells)}; cells: {', '.join(c.id for c in loaded.cells)}")
    return chosen


def _new_document(
    loaded: LoadedScenario, options: RunOptions, cells: list[ResolvedCell], perms: Permissions, start: Settings, machine: MachineInfo
) -> RunDocument:
    return RunDocument(
        scenario=ScenarioInfo(name=loaded.name, path=loaded.path, description=loaded.description),
        command=options.command,
        started_at=datetime.now(timezone.utc).isoformat(timespec="seconds"),
        machine=machine,
        permissions=perms.record(),
        start_settings=start,
        cell_ids=[c.id for c in cells],
        matrix_cells=[c.id for c in loaded.cells],
        plan=Plan(
            repeat=options.repeat,
            shuffle_seed=options.shuffle_seed,
            settle_ns=options.settle_ns,
            cells=list(options.cells),
            duration_ns=options.duration_ns,
            trace=options.trace,
            dma_latency_us=options.dma_latency_us,
            expect_hash=expect_hash(loaded.cells),
            scenario_hash=loaded.source_hash or None,
        ),
        shard=str(options.shard) if options.shard else None,
    )


def _shaping_values(values: Mapping[str, Any]) -> dict[str, Any]:
    """The run-shaping options' values in one form, given or recorded, so that equal means the same run.

    Durations in ns, --cell as its set of globs, --shard as K/N, --dma-latency and
    --no-dma-latency both as the latency held (None: left alone), --no-trace as whether
    the run traces.  `values` has each option's value as RunOptions or the plan holds it.
    """
    return {option: tuple(sorted(set(value))) if option == "--cell" else value for option, value in values.items()}


def _shown(option: str, value: Any) -> str:
    """A run-shaping option's value as a user would have written it, or what its absence meant."""
    if option == "--duration":
        return f"--duration {units.format_duration(value)}" if value is not None else "no --duration (the scenario's)"
    if option == "--cell":
        return " ".join(f"--cell {glob}" for glob in value) if value else "no --cell (every cell)"
    if option == "--shuffle":
        return "no --shuffle" if value is None else "--shuffle (a random seed)" if value == "random" else f"--shuffle {value}"
    if option == "--settle":
        return f"--settle {units.format_duration(value)}"
    if option == "--shard":
        return f"--shard {value}" if value else "no --shard"
    if option in ("--dma-latency", "--no-dma-latency"):
        return "--no-dma-latency" if value is None else f"--dma-latency {value}"
    if option == "--no-trace":
        return "tracing (no --no-trace)" if value else "--no-trace"
    return f"{option} {value}"


def _recorded_options_differ(given: Mapping[str, Any], recorded: Mapping[str, Any]) -> None:
    """Refuse options given with --resume whose value differs from the one the run recorded, saying both.

    An option equal to the recorded one (`--duration 1s` given again to a 1 s run) changes
    nothing and is taken: a user may repeat the command line that started the run.
    """
    differ = [option for option in given if option in recorded and given[option] != recorded[option]]
    if differ:
        said = "; ".join(f"{_shown(o, given[o])} was given, but the run recorded {_shown(o, recorded[o])}" for o in differ)
        raise UsageError(
            f"runner: --resume DIR finishes DIR's run with the options it recorded: {said}; "
            f"leave out {', '.join(differ)}, or start a new run"
        )


def _resumed_document(loaded: LoadedScenario, options: RunOptions) -> RunDocument:
    """The interrupted run in --resume DIR, checked against the scenario as it is now."""
    assert options.resume
    path = results_file(options.resume)
    doc = load(path)
    problems = []
    if doc.name != loaded.name:
        problems.append(Problem(path, 1, 1, "scenario.name", f"is {doc.name!r}, but {loaded.path} is {loaded.name!r}"))
    by_id = {c.id: c for c in loaded.cells}
    for cell in doc.cells:
        now = by_id.get(cell.id)
        if now is None:
            problems.append(Problem(path, 1, 1, f"cells.{cell.id}", f"is no longer a cell of {loaded.path}"))
        elif now.spec_hash != cell.spec_hash:
            problems.append(
                Problem(path, 1, 1, f"cells.{cell.id}", f"{loaded.path} changed since this cell ran; start a new run instead of resuming")
            )
    plan = doc.plan
    if plan.expect_hash is not None and plan.expect_hash != expect_hash(loaded.cells):
        why = f"{loaded.path} changed its expectations since this run started, which judged its finished cells by the old ones"
        problems.append(Problem(path, 1, 1, "expect", f"{why}; start a new run instead of resuming"))
    if problems:
        raise ScenarioError(problems)
    doc.cells = [c for c in doc.cells if c.status is not Status.INTERRUPTED and not c.unwritten]  # redo what was cut short
    recorded = {
        "--duration": plan.duration_ns,
        "--cell": plan.cells,
        "--repeat": plan.repeat,
        "--shuffle": plan.shuffle_seed,
        "--settle": DEFAULT_SETTLE_NS if plan.settle_ns is None else plan.settle_ns,
        "--shard": str(Shard.parse(doc.shard)) if doc.shard else None,
    }
    if plan.trace is not None:  # recorded since plan.trace; an older file may be resumed with the options its start had
        recorded |= {"--dma-latency": plan.dma_latency_us, "--no-dma-latency": plan.dma_latency_us, "--no-trace": plan.trace}
    _recorded_options_differ(options.resume_options, _shaping_values(recorded))
    options.repeat = plan.repeat
    options.shuffle_seed = plan.shuffle_seed
    options.settle_ns = options.settle_ns if plan.settle_ns is None else plan.settle_ns
    options.cells = list(plan.cells)
    options.duration_ns = plan.duration_ns
    options.shard = Shard.parse(doc.shard) if doc.shard else None
    if plan.trace is not None:  # recorded since this runner: the rest of the run traces, and holds the latency, as its start did
        options.trace, options.dma_latency_us = plan.trace, plan.dma_latency_us
    doc.status, doc.finished_at = "running", None
    doc.command = options.command
    return doc


def run_scenario(loaded: LoadedScenario, options: RunOptions, backend: Optional[Backend] = None) -> int:
    """Run the selected cells of `loaded`; write results after each and a report at the end; return the exit code.

    `backend` is the machine (the real kernel unless a test passes a fake one).
    """
    with StopSignals() as stop:  # from the first process started to the last one gone: a stop is never a kill
        if backend is None:
            from runner.run.kernelbackend import KernelBackend

            backend = KernelBackend()
        try:
            code = _run(loaded, options, backend, stop)
        finally:
            backend.close()
    return stopped_late(code) if stop.requested() else code


def stopped_late(code: int) -> int:
    """The exit code of a run a stop reached after its cells, while it wrote the report or cleaned up.

    Nothing measured was cut short, and the results say so; the code still says the run was
    asked to stop (130), as for a stop at any other moment, unless it already says an error.
    """
    return int(exit_code([Status.INTERRUPTED] + ([Status.ERROR] if code == ExitCode.RUN_ERROR else [])))


def checked_cells(loaded: LoadedScenario, options: RunOptions) -> tuple[Optional[RunDocument], list[ResolvedCell]]:
    """The cells a run would run, after every check it makes before it touches the machine or writes a file;
    with --resume also the interrupted run, whose recorded plan then decides `options`.

    `runner run --list` calls this too: a baseline that cannot be read or compared, or a --resume folder that
    is no run of this scenario, is refused by the listing as by the run, not found only when it runs.
    """
    baseline = load(options.baseline) if options.baseline else None
    doc = _resumed_document(loaded, options) if options.resume else None
    cells = select_cells(loaded, options)
    if baseline is not None:
        _check_baseline(baseline, cells, loaded.cells, options, loaded.path)
    late = {why for c in cells if options.duration_ns for _, why in never_released(c.scenario.processes, options.duration_ns)}
    if late:
        raise UsageError(f"runner: --duration {units.format_duration(options.duration_ns or 0)}: " + "; ".join(sorted(late)))
    if len(cells) * options.repeat > MAX_REPEAT:  # the run order is planned up front: a billion cell runs would fill memory first
        raise UsageError(
            f"runner: --repeat {options.repeat:,} of {len(cells):,} cells is {len(cells) * options.repeat:,} cell runs; "
            f"at most {MAX_REPEAT:,} in one run"
        )
    return doc, cells


def _run(loaded: LoadedScenario, options: RunOptions, backend: Backend, stop: StopSignals) -> int:
    doc, cells = checked_cells(loaded, options)
    by_id = {c.id: c for c in cells}
    start = backend.start_settings()
    perms = backend.preflight([c.scenario for c in cells], start, options.allow_degraded, options.allow_priority_99)
    for problem in perms.missing:
        warn(f"{problem}; running degraded")
    backend.prepare(options.trace)
    if doc is None:
        stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
        folder = options.out or os.path.join("reports", slug(loaded.name), stamp)  # a name is a label, not a path: `..` stays inside
        held = outdir.claim(folder)
        doc = _new_document(loaded, options, cells, perms, start, backend.machine())
    else:
        folder = options.resume or ""
        held = outdir.claim(folder, resume=True)
    try:
        return _run_units(loaded, _Claimed(options, doc, by_id, folder, start, stop, backend))
    finally:
        held.release()


def _check_baseline(
    baseline: RunDocument, cells: list[ResolvedCell], loaded_cells: list[ResolvedCell], options: RunOptions, path: str
) -> None:
    """Refuse, before any cell runs, a baseline the finished run could not be compared with (the comparison's own refusals).

    The cells this run will record are known now, with their resolved scenarios and length:
    a baseline of another scenario, or whose cells ran another spec or for another duration,
    is found here rather than after the whole run, whose JUnit would then say nothing of it.
    """
    planned = RunDocument(
        plan=Plan(duration_ns=options.duration_ns),
        shard=str(options.shard) if options.shard else None,
        cell_ids=[c.id for c in cells],
        matrix_cells=[c.id for c in loaded_cells],
    )
    planned.cells = [CellResult(id=c.id, spec_hash=c.spec_hash, spec=spec_json(c.scenario), status=Status.PASSED) for c in cells]
    assert options.baseline is not None
    check_comparable(baseline, planned, options.baseline, path)
    check_common(baseline, planned, options.baseline, path)  # a shard that holds no cell is refused only for another scenario


@dataclass
class _Loop:
    """How a run's cell loop ended: the statuses so far, a write error that stopped it, whether every cell ran."""

    statuses: list[Status]
    write_error: Optional[OSError] = None
    ran_all: bool = False

    def final(self, stopped: bool) -> list[Status]:
        """The statuses that decide the run: an interrupt, a write error, or a loop that neither finished nor
        was stopped (a bug) each add theirs, so such a run is never "passed"."""
        if stopped:
            return [*self.statuses, Status.INTERRUPTED]
        if self.write_error is not None or not self.ran_all:
            return [*self.statuses, Status.ERROR]
        return self.statuses


@dataclass
class _Claimed:
    """A run that holds its folder: what the cell loop and the conclusion share."""

    options: RunOptions
    doc: RunDocument
    by_id: dict[str, ResolvedCell]
    folder: str
    start: Settings
    stop: StopSignals
    backend: Backend


def _run_units(loaded: LoadedScenario, run: _Claimed) -> int:
    """The cell loop of a claimed folder, then the report: every way out saves what finished."""
    options, doc, folder, stop = run.options, run.doc, run.folder, run.stop
    doc.folder = os.path.abspath(folder)
    results_path = os.path.join(folder, "results.json")
    store = ResultsStore(results_path)
    try:
        store.begin(doc)
    except OSError as exc:
        raise from_os_error(exc, "cannot write the results file") from None
    units_left = plan_units(list(run.by_id), options.repeat, options.shuffle_seed, [(c.id, c.repeat) for c in doc.cells])
    skipped = f", {len(doc.cells)} already done" if doc.cells else ""
    empty = _empty_shard(loaded, options, run.by_id)
    if empty:
        say(f"{loaded.name}: {empty}; nothing to run, results in {results_path}")
    else:
        say(f"{loaded.name}: {len(units_left)} cell{'s' if len(units_left) != 1 else ''} to run{skipped}, results in {results_path}")
    if options.shuffle_drawn and options.shuffle_seed is not None:
        say(f"shuffled with seed {options.shuffle_seed}: --shuffle {options.shuffle_seed} runs the cells in this order again")
    with run.backend.hold_dma_latency(options.dma_latency_us) as dma:
        doc.machine.dma_latency = dma  # the cells this run records carry the hold they ran under
        if options.dma_latency_us is not None and not dma.held:
            warn(f"{dma.note}; CPUs may enter deep idle states during the run (--no-dma-latency to not try)")
        loop = _cell_loop(units_left, run, store)
    run.backend.cells_done()
    statuses = loop.final(stop.requested())
    stop.late_words = "runner: asked to stop; the cells are done, finishing the results and the report"
    doc.finished_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
    doc.status = worst(statuses).value
    try:
        store.finish(doc)
    except OSError as exc:
        loop.write_error = loop.write_error or exc
    if loop.write_error is not None:
        error = loop.write_error
        note(
            f"runner: cannot write {error.filename or results_path}: {error.strerror or error}; the run stopped. {results_path} keeps "
            f"every cell that finished before; the cell in flight is marked error where it could be written; {_remedy(error)}, "
            f"then finish the run with --resume {folder}"
        )
        return int(ExitCode.RUN_ERROR)  # a write error during the run, a full disk too (errors.FULL_DISK)
    from runner.report.publish import finish

    try:
        regressions = finish(
            doc,
            folder,
            options.baseline,
            options.thresholds,
            options.report,
            options.plots,
            dict(os.environ),
            junit=options.junit,
            history=options.history,
        )
    except OSError as exc:
        raise from_os_error(exc, "cannot write the report", before_run=False) from None
    except RunnerError as refused:  # the baseline could not be compared with what ran (checked against the plan before)
        if Status.INTERRUPTED not in statuses or isinstance(refused, OutputError):  # a plot a full disk refused, say
            raise
        note(f"{refused}\nrunner: the run was stopped before it could be compared with the baseline; no comparison was made")
        regressions = 0
    verdict = f"{empty}; nothing ran" if empty and worst(statuses) is Status.PASSED else worst(statuses).value
    say(f"{loaded.name}: {verdict}; results: {results_path}")
    if options.lava:  # last, so a lab reads the verdicts after the lines that explain them
        from runner.report.lava import lava_calls, send

        send(lava_calls(doc))
    return int(exit_code(statuses, regressions))


def _remedy(error: OSError) -> str:
    """What lets a run a write error stopped be finished in its own folder (`--resume` writes there again)."""
    return {
        errno.ENOSPC: "free some space",
        errno.EDQUOT: "free some space (the disk quota is used up)",
        errno.EIO: "check the disk (an I/O error)",
    }.get(error.errno or 0, "make it writable")


def _empty_shard(loaded: LoadedScenario, options: RunOptions, cells: Mapping[str, ResolvedCell]) -> str:
    """Why a run has no cell at all: its shard holds none of the matrix (more shards than cells), or "".

    A CI matrix of N jobs may well outnumber a scenario's cells; such a job stays green (exit 0),
    but its words say nothing ran rather than a bare "passed" that reads as cells that passed.
    """
    if cells or options.shard is None:
        return ""
    count = len(loaded.cells)
    return f"shard {options.shard} holds none of the scenario's {count} cell{'s' if count != 1 else ''}"


def _cell_loop(units: list[Unit], run: _Claimed, store: ResultsStore) -> _Loop:
    """Run the cells one after another, recording each as it finishes; stop at a stop request or a write error."""
    options, doc, folder, stop, backend = run.options, run.doc, run.folder, run.stop, run.backend
    loop = _Loop([c.status for c in doc.cells])
    progress = Progress(len(units), options.settle_ns / 1e9, options.live, options.quiet)

    def follow_line(line: str) -> None:
        progress.clear()
        say(line)

    follow = follow_line if options.follow else None
    try:
        for n, unit in enumerate(units):
            if n and options.settle_ns:
                _settle(options.settle_ns, stop)
            if stop.requested():
                return loop
            cell = run.by_id[unit.cell]
            duration = options.duration_ns or cell.scenario.duration
            progress.start(unit, options.repeat, duration / 1e9)
            cell_options = CellOptions(
                duration,
                options.allow_degraded,
                follow,
                progress.line if not options.follow else None,
                stop.requested,
                trace=options.trace,
                allow_priority_99=options.allow_priority_99,
            )
            began = time.monotonic()
            relative = cell_dir(unit.cell, unit.repeat, options.repeat > 1)
            with collector_paused():
                result, loop.write_error, window_end = _one_cell(cell, folder, relative, run.start, cell_options, backend)
                progress.finish(time.monotonic() - began)
                loop.statuses.append(result.status)
                try:
                    _record(doc, result, unit, store, window_end)
                except OSError as exc:
                    doc.cells.remove(result)
                    loop.write_error = loop.write_error or exc
            say(render_cell(result, backend.pid_width()))
            if loop.write_error is not None or stop.requested():
                return loop
        loop.ran_all = True
        return loop
    finally:
        progress.clear()


def _one_cell(
    cell: ResolvedCell, root: str, relative: str, start: Settings, options: CellOptions, backend: Backend
) -> tuple[CellResult, Optional[OSError], Optional[int]]:
    """Run, evaluate and store one cell in `root`/`relative`; a write error (a full disk) comes back beside the result it spoiled.

    Also returned: when the cell's measured window ended (CLOCK_MONOTONIC ns; None if it never began).
    The cell's folders below the run's are made, or found, as folders: never a link (safefs.make_folders).
    """
    folder = os.path.join(root, relative)
    started_at = datetime.now(timezone.utc).isoformat(timespec="seconds")
    keep = cell.scenario.samples.mode is not SamplesMode.NONE
    writer = SamplesWriter(os.path.join(folder, "samples.csv.gz")) if keep else None
    options = replace(options, samples=_SamplesFile(writer) if writer else None)
    try:
        try:
            make_folders(root, relative)
            raw = backend.run_cell(cell, folder, start, options)
        except OSError as exc:  # the cell's folder or sample buffer could not be made: nothing ran
            if writer is not None:
                writer.abort()
            return unrun(cell, f"the cell's files could not be created: {exc.strerror or exc} ({exc.filename})", started_at), exc, None
        scenario = cell.scenario.replace(duration=options.duration_ns)
        result = evaluate(cell, scenario, raw, options.allow_degraded, options.allow_priority_99)
    except BaseException:  # a defect: no half-written samples file or open descriptor is left behind
        if writer is not None:
            writer.abort()
        raise
    end = raw.timeline.end_ns
    if writer is None:
        return result, None, end
    try:
        writer.close()
    except OSError as exc:
        return with_write_error(result, writer.path, exc), exc, end
    result.samples_file = writer.path
    return result, None, end


class _SamplesFile:
    """The cell's samples file as the shell's sink: callbacks in, rows of samples.csv.gz out."""

    def __init__(self, writer: SamplesWriter):
        self.writer = writer

    def write(
        self, key: str, tid: int, samples: list[Sample], mutexes: Sequence[str] = (), holders: Mapping[int, str] = NO_HOLDERS
    ) -> None:
        self.writer.writerows(sample_rows(key, tid, samples, mutexes, holders))


def _settle(settle_ns: int, stop: StopSignals) -> None:
    """The pause between cells, cut short by a stop request."""
    until = time.monotonic() + settle_ns / 1e9
    while not stop.requested() and (left := until - time.monotonic()) > 0:
        time.sleep(min(left, 0.1))


def _record(doc: RunDocument, result: CellResult, unit: Unit, store: ResultsStore, window_end: Optional[int] = None) -> None:
    """Add a finished cell to the document and store it at once (`window_end`: when its measured window ended)."""
    result.machine = doc.machine
    result.repeat = unit.repeat
    if result.samples_file:  # written where the run's folder is, relative to the working directory or not
        result.samples_file = os.path.relpath(os.path.abspath(result.samples_file), doc.folder)
    doc.cells.append(result)
    if window_end is not None:
        result.overhead_ns.end_to_saved = time.monotonic_ns() - window_end
    began = time.monotonic_ns()
    store.add(doc, result)
    result.overhead_ns.save = time.monotonic_ns() - began  # in the file from the run's next write on (its last one at least)
