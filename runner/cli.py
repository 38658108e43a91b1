"""Command line: parse arguments, call one function per command, map errors to exit codes.

No logic lives here beyond that: every command is a call into the module that owns it.
"""

from __future__ import annotations

import argparse
import errno
import json
import os
import re
import signal
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

from runner import __version__
from runner import options as opt
from runner.collector import collector_paused
from runner.errors import MAX_MESSAGE, ExitCode, RunnerError, ScenarioError, UsageError, bounded, did_you_mean, from_os_error
from runner.terminal import note, put, say, stdout_lost, warn

COMMANDS = ("run", "validate", "schema", "ps", "watch", "report", "compare", "merge", "history", "import-rtapp", "completion")
_TOP_HELP = """\
usage: runner SCENARIO.yaml [options]      run a scenario (every cell of its matrix), write results and a report
       runner validate FILE...             check scenario files, print every problem
       runner schema [--results]           print the JSON Schema of the scenario format (or of results.json)
       runner ps PID|NAME                  ps-style thread table of a live process
       runner watch PID|NAME...            measure running processes from outside, write results and a report
       runner report RESULTS [-o FILE]     re-render the markdown report (and plots) of a run
       runner compare BASE NEW             compare two runs; exit 1 on a regression
       runner merge DIR... --out DIR       combine shard results into one results file and report
       runner history FILE [--import R...] the trend report of a --history (fills it from old results with --import)
       runner import-rtapp JSON [-o FILE]  convert an rt-app workload into a scenario (notes on stderr)
       runner completion bash|zsh|tcsh     print a shell completion script
       runner --version

Run `runner run --help` for the run options (SCENARIO.yaml is short for `runner run SCENARIO.yaml`).
RESULTS, BASE and NEW are results.json files or the folders holding them.

exit codes: 0 ok, 1 an expectation failed or a regression against the baseline, 2 invalid input,
            3 missing permission, 4 run error (worker crash, timeout, full disk), 70 a bug in the runner
            (the traceback is saved to a file), 130 interrupted
"""


def _run_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="runner run", description="Run a scenario file: spawn its processes and threads, measure, report.")
    p.add_argument("scenario", metavar="SCENARIO.yaml", help="scenario YAML file (or an rt-app workload, FILE.json)")
    p.add_argument("--list", action="store_true", help="print the expanded cells with each thread's resolved settings; run nothing")
    p.add_argument("--duration", metavar="D", help="override the scenario's duration, e.g. 2s (100ms to 24h)")
    opt.CELLS.add(p, help="run only cells whose id matches (repeatable)")
    opt.OUT.add(p, help="results folder (default reports/<scenario>/<UTC timestamp>)")
    p.add_argument("--follow", action="store_true", help="print a line per callback, as the ros2-realtime-examples do")
    p.add_argument(
        "--allow-degraded", action="store_true", help="run even without the rights to apply every setting; mark affected threads degraded"
    )
    opt.ALLOW_PRIORITY_99.add(p, help="allow scenario threads at RT priority 99 (above the runner's watchdog)")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    m = p.add_argument_group("matrix runs")
    m.add_argument("--repeat", metavar="N", help="run every cell N times; the report gives the spread")
    m.add_argument(
        "--shuffle", nargs="?", const="random", type=_seed, metavar="SEED", help="run cells in a random order (a SEED repeats an order)"
    )
    m.add_argument("--settle", metavar="D", help="pause between cells (default 500ms, at most 1h)")
    m.add_argument("--shard", metavar="K/N", help="run the K-th of N disjoint parts of the matrix (for CI matrix jobs)")
    m.add_argument("--resume", metavar="DIR", help="finish the interrupted run in DIR; finished cells are not run again")
    machine = p.add_argument_group("machine")  # one group: argparse prints a group per call, even under the same title
    d = machine.add_mutually_exclusive_group()
    d.add_argument(
        "--dma-latency",
        metavar="US",
        help="hold /dev/cpu_dma_latency at US microseconds while cells run, as cyclictest does (default 0: no deep CPU idle states)",
    )
    d.add_argument("--no-dma-latency", action="store_true", help="leave /dev/cpu_dma_latency alone")
    opt.NO_TRACE.add(
        machine, help="do not trace the scheduler (no wake-up latency per wake-up, no preemption attribution; /proc figures stay)"
    )
    r = p.add_argument_group("report")
    opt.BASELINE.add(r, help="compare with an earlier run; a regression makes the exit code 1")
    opt.HISTORY.add(r)
    opt.THRESHOLD.add(r)
    r.add_argument("--no-report", action="store_true", help="write results.json only")
    opt.NO_PLOTS.add(r, help="no SVG plots beside the report")
    opt.JUNIT.add(r)
    opt.LAVA.add(r, help="after the run, " + opt.LAVA_HELP)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `runner` console script; returns the exit code."""
    args = list(sys.argv[1:] if argv is None else argv)
    for stream in (sys.stdout, sys.stderr):  # a name the terminal cannot encode is shown escaped, not a crash
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None:
            reconfigure(errors="backslashreplace")
    if not args or args[0] in ("-h", "--help"):
        say(_TOP_HELP)
        return ExitCode.OK if args else ExitCode.INVALID_INPUT
    if args[0] == "--version":
        say(f"runner {__version__}")
        return ExitCode.OK
    mistyped = _mistyped_command(args[0])
    if mistyped:
        _say(mistyped)
        return ExitCode.INVALID_INPUT
    unreadable = [arg for arg in args if not _is_utf8(arg)]
    if unreadable:  # results, reports and JUnit files name their files in UTF-8: they could not be written
        for arg in unreadable:
            _say(f"runner: {_shown(arg)}: not UTF-8; expected names and paths in UTF-8, as results and reports store them: rename it")
        return ExitCode.INVALID_INPUT
    command = args[0] if args[0] in COMMANDS else "run"
    rest = args[1:] if args[0] in COMMANDS else args
    handlers: dict[str, Callable[[list[str]], int]] = {
        "run": _cmd_run,
        "validate": _cmd_validate,
        "schema": _cmd_schema,
        "ps": _cmd_ps,
        "watch": _cmd_watch,
        "report": _cmd_report,
        "compare": _cmd_compare,
        "merge": _cmd_merge,
        "history": _cmd_history,
        "import-rtapp": _cmd_import_rtapp,
        "completion": _cmd_completion,
    }
    if command in _READ_DOCUMENTS:  # they build and walk documents of many records, none in a cycle (runner.collector)
        with collector_paused():
            return _guarded(handlers[command], rest)
    return _guarded(handlers[command], rest)


_READ_DOCUMENTS = frozenset({"report", "compare", "merge", "history"})


def _seed(value: str) -> str:
    """--shuffle's SEED: an integer or `random`; anything else (a scenario's path after it) is said as such."""
    if value != "random" and not re.fullmatch(r"-?[0-9]+", value):  # ASCII digits: isdecimal() takes `٣` too
        raise argparse.ArgumentTypeError(f"{value!r} is no seed (an integer); give the scenario before --shuffle, or write --shuffle=SEED")
    return value


def _is_utf8(arg: str) -> bool:
    """Whether a command-line argument was valid UTF-8 (Python keeps other bytes as lone surrogates)."""
    try:
        arg.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _shown(arg: str) -> str:
    """An argument as its bytes were, those that are not UTF-8 escaped (`x\\xff.yaml`)."""
    return arg.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def _mistyped_command(word: str) -> str | None:
    """What to say when the first argument is neither a command nor a scenario (`runner comapre a b`), or None.

    `runner FILE.yaml` runs a file, so a first argument that is an option, an existing path, or names a
    .yaml, .yml or .json file is left to the run command, which reports a missing file itself.
    """
    if word in COMMANDS or word.startswith("-") or os.path.exists(word) or os.sep in word or word.endswith((".yaml", ".yml", ".json")):
        return None
    hint = did_you_mean(word, COMMANDS)
    return f"runner: unknown command {word!r}" + (hint or f"; expected one of: {', '.join(COMMANDS)}, or a scenario file (FILE.yaml)")


def _guarded(handler: Callable[[list[str]], int], argv: list[str]) -> int:
    """Run one command; turn anything it raises into one line on stderr and the documented exit code.

    This is the single boundary between the runner and the shell: no traceback passes it.
    SIGTERM stops a command as Ctrl-C does (a run turns both into a stop at its next safe point).
    """
    previous = signal.signal(signal.SIGTERM, _terminated)
    try:
        return _output_kept(handler(argv))
    except RunnerError as exc:
        _say(str(exc))
        _annotate(getattr(exc, "problems", []))
        return exc.exit_code
    except KeyboardInterrupt:
        _say("runner: interrupted")
        return ExitCode.INTERRUPTED
    except BrokenPipeError:
        return ExitCode.OK
    except OSError as exc:
        if exc.filename is None:
            return _internal_error(exc)
        error = from_os_error(exc, "cannot use", before_run=False)
        _say(str(error))
        return error.exit_code
    except SystemExit:
        raise  # argparse's own exit (2 for a usage mistake, 0 for --help)
    except Exception as exc:
        return _internal_error(exc)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _output_kept(code: int) -> int:
    """A command's exit code, once its output is known to have reached stdout, or why it did not.

    A reader that closed the pipe early (`| head`) took what it wanted: the code stays the
    command's.  Output lost otherwise (a full disk, stdout closed) is said, and a command that
    would have exited 0 exits 4: its user did not get what it printed.
    """
    lost = stdout_lost()
    if lost is None or lost.errno == errno.EPIPE:
        return code
    _say(f"runner: cannot write to standard output: {lost.strerror or lost}")
    return int(ExitCode.RUN_ERROR) if code == ExitCode.OK else code


def _terminated(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def _say(text: str) -> None:
    try:
        note(text)
    except (OSError, ValueError):
        pass


def _internal_error(exc: BaseException) -> int:
    """A bug: one line for the user, the whole traceback in a file for the bug report.

    The file is new, of a name no one can guess, readable by its owner alone (mkstemp: O_EXCL,
    O_NOFOLLOW, 0600): in a shared /tmp, a name known in advance could be a link another user
    put there, which an open of that name would write through, as root too.
    """
    import tempfile  # here, not at the top: only a bug needs them, and every command would pay for both
    import traceback

    text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    where = os.environ.get("RUNNER_CRASH_DIR") or tempfile.gettempdir()
    try:
        fd, path = tempfile.mkstemp(prefix=f"runner-bug-{time.strftime('%Y%m%dT%H%M%S')}-", suffix=".txt", dir=where)
        with os.fdopen(fd, "w", encoding="utf-8", errors="backslashreplace") as handle:
            handle.write(f"runner {__version__}\ncommand: {' '.join(map(_shown, sys.argv))}\n\n{text}")
        saved = f"the traceback is in {path}"
    except (OSError, ValueError):
        saved = f"the traceback could not be saved ({type(exc).__name__}: {exc})"
    _say(f"runner: internal error (a bug in the runner, please report it): {type(exc).__name__}: {exc}; {saved}")
    return ExitCode.INTERNAL_ERROR


def _print_warnings(warnings: Sequence[object]) -> None:
    for warning in warnings:
        note(str(warning))
    _annotate(warnings)


def _annotate(problems: Sequence[object]) -> None:
    """In GitHub Actions, problems in a file are also annotations at their line (docs/nightly.md, "CI systems")."""
    env = dict(os.environ)
    if env.get("GITHUB_ACTIONS", "") != "true":
        return  # not in GitHub Actions: nothing to import
    from runner.errors import Problem
    from runner.report import github

    if github.enabled(env):
        for problem in problems:
            if isinstance(problem, Problem):
                say(github.for_problem(problem, github.workspace_path(problem.file, os.getcwd(), env.get("GITHUB_WORKSPACE"))).command())


def _validate_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="runner validate", description="Check scenario files; print every problem as file:line:col.")
    p.add_argument("files", nargs="+", metavar="FILE")
    return p


def _cmd_validate(argv: list[str]) -> int:
    ns = _validate_parser().parse_args(argv)
    from runner.scenario.listing import expansion
    from runner.scenario.loader import load_scenario

    worst = ExitCode.OK
    for path in ns.files:
        try:
            loaded = load_scenario(path, for_run=False)  # what this machine lacks, and this user's rights, are warnings here
        except ScenarioError as exc:
            note(str(exc))
            _annotate(exc.problems)
            worst = ExitCode.INVALID_INPUT
            continue
        _print_warnings(loaded.warnings)
        count = len(loaded.cells)
        say(f"{path}: ok ({count} cell{'s' if count != 1 else ''})")
        for line in expansion(loaded):  # count: cpus, pin: each, priospread, distance: what they resolve to here
            say("  " + line)
    return worst


def _schema_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="runner schema",
        description="Print the JSON Schema of the scenario format "
        "(runner.schema.json), or with --results that of results.json (results.schema.json).",
    )
    p.add_argument("--results", action="store_true", help="the schema of results.json instead of the scenario's")
    return p


def _cmd_schema(argv: list[str]) -> int:
    ns = _schema_parser().parse_args(argv)
    if ns.results:
        from runner.results.document import results_schema

        say(json.dumps(results_schema(), indent=2))
        return ExitCode.OK
    from runner.scenario.schema import scenario_schema

    say(json.dumps(scenario_schema(), indent=2))
    return ExitCode.OK


def _ps_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="runner ps", description="Thread table of live processes, as ps -L -o tid,comm,rtprio,cls,psr prints it."
    )
    p.add_argument(
        "target",
        metavar="PID|NAME",
        help="a PID, or a process name: every thread of the processes whose COMMAND it is "
        "(as the seed's `ps -C NAME -L` printed; procps 4 selects threads by their own name instead)",
    )
    p.add_argument("-o", "--columns", default="tid,comm,rtprio,cls,psr", help="columns: tid,comm,rtprio,cls,psr,ni,pri,cpus,nvcsw,nivcsw")
    return p


def _cmd_ps(argv: list[str]) -> int:
    ns = _ps_parser().parse_args(argv)
    from runner import units
    from runner.results.pstable import parse_columns, render_ps
    from runner.run.kernel import find_pids, pid_width, thread_rows

    columns = parse_columns(ns.columns)
    try:
        pid = units.parse_pid(ns.target)
    except units.UnitError as exc:
        raise UsageError(f"runner ps: {exc}") from None
    pids = [pid] if pid is not None else find_pids(ns.target)
    rows = [row for pid in pids for row in thread_rows(pid)]
    if not rows:
        raise UsageError(f"runner ps: no live process matches {ns.target!r}")
    say(render_ps(rows, columns, pid_width()))
    return ExitCode.OK


def _watch_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="runner watch",
        description="Measure running processes from outside (their threads' settings, switches, faults, CPU time) "
        "and write results.json and report.md as a run does; nothing is changed unless --rule asks.",
    )
    p.add_argument("targets", nargs="+", metavar="PID|NAME", help="a PID, or a process name (every live process whose COMMAND it is)")
    p.add_argument("--duration", default="10s", help="how long to watch (default 10s); Ctrl-C stops early and keeps what was measured")
    opt.OUT.add(p, help="results folder (default reports/watch/<UTC time>)")
    p.add_argument(
        "--rule",
        action="append",
        default=[],
        metavar="PATTERN=SCHED@CPUS",
        help="a thread rule to apply to matching threads: PATTERN=SCHED@CPUS (the threads keep it after the watch)",
    )
    opt.ALLOW_PRIORITY_99.add(p, help="let a rule ask for RT priority 99 (refused otherwise)")
    opt.NO_PLOTS.add(p, help="write the report without plots")
    opt.NO_TRACE.add(p, help="do not trace the scheduler (tracefs), as runner SCENARIO --no-trace")
    return p


def _cmd_watch(argv: list[str]) -> int:
    ns = _watch_parser().parse_args(argv)
    from runner import outdir
    from runner.printable import for_terminal
    from runner.report.cellview import render_cell
    from runner.report.publish import write_report
    from runner.run.kernel import pid_width
    from runner.scenario.model import MAX_RUN, MIN_RUN
    from runner.session import StopSignals, exit_code, parse_duration
    from runner.watch import default_folder, parse_rule, resolve_targets, watch

    duration = parse_duration(ns.duration, "--duration", MIN_RUN, MAX_RUN)
    rules = [parse_rule(r) for r in ns.rule]
    from runner.run.kernel import online_cpus
    from runner.run.preflight import check_rules

    check_rules(rules, ns.allow_priority_99, set(online_cpus()))
    pids = resolve_targets(ns.targets)
    held = outdir.claim(ns.out or default_folder())
    try:
        with StopSignals() as stop:
            doc = watch(pids, duration, held.folder, rules, stop.requested, trace=not ns.no_trace)
        doc.command = ["runner", "watch", *argv]
        doc.folder = held.folder
        path = os.path.join(held.folder, "results.json")
        doc.save(path)
        report = write_report(doc, held.folder, None, not ns.no_plots, pid_width())
    finally:
        held.release()
    cell = doc.cells[0]
    say(render_cell(cell, pid_width()))
    if cell.trace is not None and not cell.trace.enabled:
        say(for_terminal(f"watch: scheduler trace not taken: {cell.trace.reason}"))
    say(for_terminal(f"watch: {cell.status.value}{': ' + cell.reason if cell.reason else ''}; results: {path}; report: {report}"))
    return exit_code([cell.status])


def _cmd_run(argv: list[str]) -> int:
    ns = _run_parser().parse_args(argv)
    from runner.scenario.loader import load_scenario

    loaded = load_scenario(ns.scenario, for_run=not ns.list)  # --list, as validate: what this machine lacks is a warning
    _print_warnings(loaded.warnings)
    from runner.session import RunOptions, checked_cells, run_scenario

    options = RunOptions.from_namespace(ns, env=dict(os.environ))  # --list checks every option as a run would
    if ns.list:
        from runner.run.kernel import current_settings, online_cpus
        from runner.scenario.listing import render

        _, cells = checked_cells(loaded, options)  # --baseline and --resume too: read and checked, as the run would
        say(render(loaded, current_settings(), online_cpus(), cells, options.duration_ns))
        return ExitCode.OK
    return run_scenario(loaded, options)


def _report_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="runner report", description="Re-render the markdown report of a run from its results, without re-running."
    )
    p.add_argument("results", metavar="RESULTS", help="results.json or the folder holding it")
    opt.OUTPUT.add(p, help="report file (default: report.md beside the results); - for stdout")
    opt.BASELINE.add(p, help="add a comparison with an earlier run")
    opt.THRESHOLD.add(p)
    opt.NO_PLOTS.add(p)
    x = p.add_argument_group("cyclictest formats (instead of the report, unless -o is given too)")
    x.add_argument("--histogram", metavar="FILE", help="latency histogram as `cyclictest -h` prints it (OSADL plots read it); - for stdout")
    x.add_argument("--histogram-max", metavar="US", help="--histogram's size in microseconds (cyclictest -h US; default 1000)")
    x.add_argument("--json", metavar="FILE", help="latency summary in the shape of `cyclictest --json`; - for stdout")
    x.add_argument(
        "--hdr",
        metavar="FILE",
        help="latency as an HdrHistogram log (HistogramLogProcessor and HdrHistogram's plotters read it); - for stdout",
    )
    x.add_argument("--cell", metavar="ID", help="the cell to export (with --histogram, --json or --hdr), when the run has several")
    labs = p.add_argument_group("lab formats: LAVA, KernelCI's KCIDB (instead of the report, unless -o is given too)")
    opt.LAVA.add(labs, help=opt.LAVA_HELP + "; exits as the run did")
    labs.add_argument("--kcidb", metavar="FILE", help="the run as KCIDB v5.3 JSON for you to submit to KernelCI; - for stdout")
    labs.add_argument("--kcidb-origin", metavar="NAME", help="--kcidb's origin (lowercase letters, digits, _; default runner)")
    labs.add_argument(
        "--kcidb-build", metavar="ID", help="--kcidb: test this KCIDB build (ORIGIN:ID) instead of describing the running kernel"
    )
    labs.add_argument("--kcidb-url", metavar="URL", help="--kcidb: where the results folder is published (output_files link there)")
    return p


def _cmd_report(argv: list[str]) -> int:
    ns = _report_parser().parse_args(argv)
    from runner.outdir import REPORT_NAME, writable_file
    from runner.report.compare import thresholds_for
    from runner.report.markdown import render_run
    from runner.report.publish import compare_files, comparison_statuses, report_files, say_comparison
    from runner.results.read import load
    from runner.session import exit_code

    _check_export_options(ns)
    for option, target in (("-o", ns.output), ("--json", ns.json), ("--histogram", ns.histogram), ("--hdr", ns.hdr), ("--kcidb", ns.kcidb)):
        if target and target != "-":
            writable_file(target, option)
    doc = load(ns.results)
    if ns.histogram or ns.json or ns.hdr or ns.kcidb:
        _export(doc, ns)
    statuses = []
    if ns.lava:
        from runner.report.labs import run_statuses
        from runner.report.lava import lava_calls, send

        send(lava_calls(doc))
        statuses = run_statuses(doc)  # decided as the run decided on its cells (session.exit_code)
    if not ns.output and (ns.histogram or ns.json or ns.hdr or ns.kcidb or ns.lava):
        return int(exit_code(statuses))
    section, regressions, cmp = None, 0, None
    thresholds = thresholds_for(ns.threshold, ns.baseline)
    if ns.baseline:  # decided as `runner compare` decides on the same files
        section, cmp = compare_files(ns.baseline, doc, ns.results, thresholds)
        regressions, statuses = cmp.regressions, statuses + comparison_statuses(cmp, ns.results)
    if ns.output == "-":
        say(render_run(doc, None, section, compared=cmp, cwd=os.getcwd()))
    else:
        if not ns.output and not (os.path.isdir(ns.results) or os.path.isfile(ns.results)):
            raise UsageError(
                f"runner report: {ns.results} is not a file in a results folder (a pipe?): there is no folder to write "
                f"{REPORT_NAME} beside; give -o FILE, or -o - for standard output"
            )
        # A folder named is where its report goes, never where a results.json link inside it leads (doc.folder).
        folder = os.path.abspath(ns.results) if os.path.isdir(ns.results) else doc.folder
        target = os.path.abspath(ns.output) if ns.output else os.path.join(folder, REPORT_NAME)
        try:
            os.makedirs(os.path.dirname(target), exist_ok=True)  # as writable_file found it could be
            path, failed = report_files(
                doc,
                os.path.dirname(target),
                section,
                not ns.no_plots,
                name=os.path.basename(target),
                quiet_input_errors=True,
                named=bool(ns.output),
                compared=cmp,
            )
        except OSError as exc:
            raise from_os_error(exc, "cannot write the report", path=target) from None
        say(f"report: {path}")
        if cmp is not None:
            say_comparison(cmp, ns.baseline, ns.results, path)
        if failed is not None:  # a samples file the plots could not read is this command's input: its error, report written
            raise failed
    return int(exit_code(statuses, regressions))


def _check_export_options(ns: argparse.Namespace) -> None:
    """Refuse --cell and --histogram-max without the export they shape: the report covers every cell, and
    taking them silently would let a user believe the report was cut to one cell or one size."""
    if ns.cell is not None and not (ns.histogram or ns.json or ns.hdr):
        raise UsageError(
            f"runner report: --cell {ns.cell} chooses the cell to export; give --histogram FILE, --json FILE or --hdr FILE too"
        )
    if ns.histogram_max is not None and not ns.histogram:
        raise UsageError(f"runner report: --histogram-max {ns.histogram_max} sets the size of the histogram; give --histogram FILE too")
    _check_kcidb_options(ns)
    given = (("--histogram", ns.histogram), ("--json", ns.json), ("--hdr", ns.hdr), ("--lava", ns.lava), ("--kcidb", ns.kcidb))
    exports = [option for option, value in given if value]
    if sum(value == "-" for _, value in given) > 1:
        raise UsageError("runner report: only one export can go to standard output (-); give the others a FILE")
    if exports and not ns.output and (ns.baseline or ns.threshold):
        option = "--baseline" if ns.baseline else "--threshold"
        raise UsageError(
            f"runner report: {option} compares the report with a baseline, but {' and '.join(exports)} alone write no report "
            f"({'and hold no comparison' if ns.lava else 'and decide no exit code'}); give -o FILE too, or run runner compare"
        )


def _check_kcidb_options(ns: argparse.Namespace) -> None:
    """--kcidb-origin, --kcidb-build and --kcidb-url: only with --kcidb, and each as KCIDB's schema takes it."""
    import urllib.parse

    from runner.report import kcidb

    for option, value in (("--kcidb-origin", ns.kcidb_origin), ("--kcidb-build", ns.kcidb_build), ("--kcidb-url", ns.kcidb_url)):
        if value is not None and not ns.kcidb:
            raise UsageError(f"runner report: {option} {value} shapes the KCIDB export; give --kcidb FILE too")
    if ns.kcidb_origin is not None and not kcidb.ORIGIN.fullmatch(ns.kcidb_origin):
        raise UsageError(f"runner report: --kcidb-origin {ns.kcidb_origin!r}: expected lowercase letters, digits and _ (KCIDB's origins)")
    if ns.kcidb_build is not None and not kcidb.ID.fullmatch(ns.kcidb_build):
        raise UsageError(f"runner report: --kcidb-build {ns.kcidb_build!r}: expected a KCIDB build id, ORIGIN:ID (e.g. maestro:67a1...)")
    if ns.kcidb_url is not None:
        parts = urllib.parse.urlsplit(ns.kcidb_url)
        if not parts.scheme or not (parts.netloc or parts.path) or any(c.isspace() for c in ns.kcidb_url):
            raise UsageError(f"runner report: --kcidb-url {ns.kcidb_url!r}: expected a URL such as https://lab.example/runs/42/")


def _export(doc: Any, ns: argparse.Namespace) -> None:
    """Write the cyclictest-format histogram, JSON summary or HdrHistogram log of one cell, and the KCIDB document of the run."""
    from runner.report.export import histogram_text, json_summary, pick_cell
    from runner.report.hdrlog import hdr_log
    from runner.safefs import write_named
    from runner.session import parse_number

    size = 1000 if ns.histogram_max is None else parse_number(ns.histogram_max, "runner report: --histogram-max", 1, 1_000_000)  # µs
    exports: list[tuple[str | None, Callable[[], str]]] = [(ns.kcidb, lambda: _kcidb_text(doc, ns))]  # the whole run
    if ns.histogram or ns.json or ns.hdr:  # one cell
        cell = pick_cell(doc, ns.cell)
        exports[:0] = [
            (ns.histogram, lambda: histogram_text(cell, size)),
            (ns.json, lambda: json.dumps(json_summary(doc, cell), indent=2) + "\n"),
            (ns.hdr, lambda: hdr_log(doc, cell)),
        ]
    for target, text in exports:
        if not target:
            continue
        if target == "-":
            put(text())
            continue
        try:
            write_named(target, text().encode("utf-8"))
        except OSError as exc:
            raise from_os_error(exc, "cannot write the export", path=target) from None
        say(f"wrote {target}")


def _kcidb_text(doc: Any, ns: argparse.Namespace) -> str:
    from runner.report.kcidb import DEFAULT_ORIGIN, kcidb_document

    data = kcidb_document(doc, ns.kcidb_origin or DEFAULT_ORIGIN, ns.kcidb_build, ns.kcidb_url)
    return json.dumps(data, indent=1, ensure_ascii=False) + "\n"


def _compare_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="runner compare", description="Compare a run with a baseline, cell by cell; exit 1 on a regression.")
    p.add_argument("base", metavar="BASE", help="the baseline: results.json or its folder")
    p.add_argument("new", metavar="NEW", help="the run to check: results.json or its folder")
    opt.THRESHOLD.add(p)
    opt.OUTPUT.add(p, help="also write the markdown comparison to FILE")
    opt.JUNIT.add(p, help="also write the comparison as JUnit XML to FILE (a regression is a failed test case)")
    return p


def _cmd_compare(argv: list[str]) -> int:
    ns = _compare_parser().parse_args(argv)
    from runner.outdir import writable_file
    from runner.report.compare import parse_threshold, thresholds_with
    from runner.report.publish import append_step_summary, ci_outputs, compare_files, comparison_statuses
    from runner.results.read import load
    from runner.safefs import write_named
    from runner.session import exit_code

    junit = writable_file(ns.junit, "--junit") if ns.junit else None
    if ns.output:
        writable_file(ns.output, "-o")
    new = load(ns.new)
    section, cmp = compare_files(ns.base, new, ns.new, thresholds_with(parse_threshold(t) for t in ns.threshold))
    regressions = cmp.regressions
    say(section)
    if ns.output:
        try:
            write_named(ns.output, section)
        except OSError as exc:
            raise from_os_error(exc, "cannot write the comparison", path=ns.output) from None
    append_step_summary(section, dict(os.environ))
    ci_outputs(new, cmp, junit, dict(os.environ), run=False)
    return int(exit_code(comparison_statuses(cmp, ns.new), regressions))


def _merge_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="runner merge", description="Combine shard results of one scenario into one results file and report.")
    p.add_argument("inputs", nargs="+", metavar="DIR", help="results folders (or results.json files) of the shards")
    opt.OUT.add(p, help="folder for the merged results.json and report.md", required=True)
    opt.BASELINE.add(p, help="compare the merged run with an earlier run; a regression makes the exit code 1")
    opt.HISTORY.add(p)
    opt.THRESHOLD.add(p)
    opt.NO_PLOTS.add(p)
    opt.JUNIT.add(p)
    return p


def _cmd_merge(argv: list[str]) -> int:
    ns = _merge_parser().parse_args(argv)
    from runner.outdir import claim, writable_file
    from runner.report.compare import thresholds_for
    from runner.report.publish import finish
    from runner.results.document import Status
    from runner.results.merge import merge
    from runner.session import exit_code

    thresholds = thresholds_for(ns.threshold, ns.baseline, ns.history, has_history=True)
    junit = writable_file(ns.junit, "--junit") if ns.junit else None
    if ns.baseline:
        from runner.results.read import load

        load(ns.baseline)  # a baseline that cannot be read is said before the merged folder is made, as a run's is
    held = claim(ns.out, "merge folder")
    try:
        try:
            doc, errors = merge(ns.inputs, ns.out)
        except OSError as exc:
            raise from_os_error(exc, "cannot write the merged results", before_run=False) from None
        for error in errors:
            note(f"runner merge: error: {error}")
        missing = [c for c in doc.cell_ids if c not in {cell.id for cell in doc.cells}]
        if missing:
            note(f"runner merge: warning: {len(missing)} cell(s) of the matrix are in no input: {', '.join(missing)}")
        say(f"merged {len(doc.cells)} cell run(s) from {len(ns.inputs)} input(s) into {os.path.join(ns.out, 'results.json')}")
        try:
            regressions = finish(
                doc, ns.out, ns.baseline, thresholds, True, not ns.no_plots, dict(os.environ), junit=junit, history=ns.history
            )
        except OSError as exc:
            raise from_os_error(exc, "cannot write the report", before_run=False) from None
    finally:
        held.release()
    return int(exit_code([c.status for c in doc.cells] + [Status(doc.status)], regressions))


def _history_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="runner history",
        description="Write the trend report of a history (--history FILE|URL of runs and merges): per thread, wake-up latency, "
        "missed releases and involuntary switches night by night, changes of level and of environment marked.",
    )
    p.add_argument("history", metavar="FILE|URL", help="the history: an SQLite file, or postgresql://...")
    opt.OUT.add(p, help="folder for history.md and its plots (default: FILE's name with -report)")
    opt.CELLS.add(p)
    p.add_argument("--thread", action="append", default=[], metavar="GLOB", help="only threads whose key matches (repeatable)")
    p.add_argument("--since", metavar="DATE", default="", help="only nights from DATE on (2026-11-01, or an ISO time)")
    p.add_argument(
        "--import",
        dest="imports",
        nargs="+",
        default=[],
        metavar="RESULTS",
        help="first add these results (files or folders), oldest first, each judged against the nights before it",
    )
    opt.THRESHOLD.add(p)
    opt.JUNIT.add(p, help="with --import: the last night's verdicts against the history as JUnit XML")
    opt.NO_PLOTS.add(p)
    return p


def _cmd_history(argv: list[str]) -> int:
    ns = _history_parser().parse_args(argv)
    from runner.history.apply import judged_into
    from runner.history.section import headline
    from runner.history.store import is_url, open_store
    from runner.history.trend import write
    from runner.outdir import writable_file
    from runner.report.compare import parse_threshold, thresholds_with
    from runner.report.publish import ci_outputs
    from runner.results.read import load

    thresholds = thresholds_with(parse_threshold(t) for t in ns.threshold)
    junit = writable_file(ns.junit, "--junit") if ns.junit else None
    if junit and not ns.imports:
        raise UsageError("runner history: --junit writes the verdicts of a night imported; give --import RESULTS too")
    docs = sorted(((load(path), path) for path in ns.imports), key=lambda pair: pair[0].started_at)
    out = ns.out or ("history-report" if is_url(ns.history) else os.path.splitext(ns.history)[0] + "-report")
    with open_store(ns.history) as store:
        last = None
        for doc, path in docs:
            last = (doc, judged_into(store, doc, os.path.abspath(path), thresholds))
            say(f"{path}: {headline(last[1], ns.history)}")
        report = write(store, ns.history, out, ns.cell, ns.thread, ns.since, not ns.no_plots)
    say(f"history report: {report}")
    if last is not None and junit:
        ci_outputs(last[0], None, junit, dict(os.environ), run=False, history=last[1])
    return ExitCode.OK


def _import_rtapp_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="runner import-rtapp",
        description="Convert an rt-app workload (its JSON, with comments, trailing commas and repeated keys) into a runner "
        "scenario with kind: phases work. What rt-app does that the scenario does differently, or not at all, is printed "
        "on stderr and written as comments at the top of the scenario.",
    )
    p.add_argument("file", metavar="FILE.json", help="rt-app workload file")
    opt.OUTPUT.add(p, help="write the scenario to FILE.yaml (default: stdout)", metavar="FILE.yaml")
    return p


def _cmd_import_rtapp(argv: list[str]) -> int:
    ns = _import_rtapp_parser().parse_args(argv)
    from runner.safefs import write_named
    from runner.scenario.limits import MachineLimits
    from runner.scenario.loader import parse_scenario
    from runner.scenario.rtapp import convert, read
    from runner.scenario.yamlsource import load_text

    text = read(ns.file)
    conversion = convert(text, ns.file)
    for text_note in conversion.notes:
        warn(f"{ns.file}: {bounded(text_note, MAX_MESSAGE)}")  # a task's name may be 100 KB: quoted cut, as a problem's
    scenario = conversion.yaml()
    if not ns.output:
        put(scenario)
    else:
        try:
            write_named(ns.output, scenario)
        except OSError as exc:
            raise from_os_error(exc, "cannot write the scenario", path=ns.output) from None
        say(f"wrote {ns.output}")
    # What rt-app runs but a scenario cannot hold (a phase that ends holding a mutex, 1,025 instances) is
    # found by the scenario's own checks: said now, at the lines of the scenario written, not at the first run.
    where = ns.output or f"{ns.file} (as `runner import-rtapp` converts it)"
    loaded = parse_scenario(load_text(scenario, where), MachineLimits.read(), for_run=False)
    _print_warnings(loaded.warnings)  # each says `warning:` itself, at its line
    return ExitCode.OK


def _completion_parser() -> argparse.ArgumentParser:
    from runner.completion import SHELLS

    p = argparse.ArgumentParser(
        prog="runner completion",
        description="Print a shell completion script (made by shtab from runner's own options). "
        "bash: runner completion bash > ~/.local/share/bash-completion/completions/runner; "
        'zsh: runner completion zsh > "${fpath[1]}/_runner"',
    )
    p.add_argument("shell", choices=SHELLS, metavar="|".join(SHELLS))
    return p


_PARSERS: dict[str, Callable[[], argparse.ArgumentParser]] = {
    "run": _run_parser,
    "validate": _validate_parser,
    "schema": _schema_parser,
    "ps": _ps_parser,
    "watch": _watch_parser,
    "report": _report_parser,
    "compare": _compare_parser,
    "merge": _merge_parser,
    "history": _history_parser,
    "import-rtapp": _import_rtapp_parser,
    "completion": _completion_parser,
}


def _cmd_completion(argv: list[str]) -> int:
    ns = _completion_parser().parse_args(argv)
    from runner.completion import script

    put(script(_PARSERS, ns.shell, "Run Linux scheduling scenarios and report what the kernel did."))
    return ExitCode.OK
