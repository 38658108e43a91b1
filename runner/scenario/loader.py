"""Load a scenario file into fully resolved, validated cells.

This is the one entry point the rest of the runner uses: YAML (with positions) ->
matrix expansion -> per-cell substitution -> typed `Scenario` per cell -> checks
that span fields (expectation targets, names, matrix selectors) -> limits (fixed
ceilings, and this machine's when `load_scenario` reads them).  Problems are collected
and raised together, pass by pass: the YAML and the matrix, then the models of every cell,
then the checks that span fields and the limits, which need a cell that validated (the
processes that did validate are cross-checked beside an invalid one: _partial_cross_checks).

Validation is linear in the number of cells: cells that resolve to the same data are
validated once, and what spans the matrix (selector keys and values) is indexed once
rather than searched per cell.
"""

from __future__ import annotations

import functools
import json
import os
from dataclasses import dataclass, field
from typing import Any

from runner.errors import Problem, ScenarioError, did_you_mean
from runner.figures import ThreadKind, figures_of, has, measured_how
from runner.scenario import limits as lim
from runner.scenario import matrix as mx
from runner.scenario import program
from runner.scenario.matching import expectations_for, match_threads
from runner.scenario.model import (
    CPUS_CONTEXT,
    AnyProcess,
    Expectation,
    ProgramSpec,
    Resource,
    Scenario,
    Until,
    metric_figure,
    workers,
)
from runner.scenario.plan import PROGRAM_THREAD, PlannedThread, Settings, plan_process, thread_kind
from runner.scenario.typed import Invalid, parse
from runner.scenario.validate import problems_from, written_path
from runner.scenario.yamlsource import Document, Mark, load_file


@dataclass(frozen=True)
class ResolvedCell:
    """One cell: matrix values, the validated scenario, and a hash of its resolved spec.

    `expect_marks` are where each of the scenario's `expect:` items is written (the same list in
    every cell), so a verdict can point at its line: CI annotations and the results document.
    """

    id: str
    matrix: dict[str, mx.MatrixValue]
    scenario: Scenario
    expect_marks: tuple[Mark, ...] = ()

    @functools.cached_property
    def spec_hash(self) -> str:
        """A short content hash of the resolved cell (`spec_hash`), worked out when a run or a listing asks for it."""
        return spec_hash(self.scenario)


@dataclass
class LoadedScenario:
    """A scenario file, validated: its cells in run order and any warnings."""

    path: str
    name: str
    cells: list[ResolvedCell]
    warnings: list[Problem] = field(default_factory=list)
    data: Any = None  # the file's data as written (matrix and `count: cpus` unresolved)

    @functools.cached_property
    def source_hash(self) -> str:
        """The file's data as written, hashed: the same on every machine (no matrix or `count: cpus` resolved); "" without it."""
        return source_hash(self.data) if self.data is not None else ""

    @property
    def description(self) -> str:
        return self.cells[0].scenario.description


def _digest(text: str) -> str:
    """The first 16 hex digits of the SHA-256 of `text`; hashlib is imported here, as its OpenSSL costs a start 5 ms."""
    import hashlib

    return hashlib.sha256(text.encode()).hexdigest()[:16]


_NOT_SPEC = frozenset({"description", "matrix", "expect"})


def spec_json(scenario: Scenario) -> dict[str, Any]:
    """What defines a resolved cell's run: everything but its description, matrix and expectations.

    A program's `callbacks: on` (the default) is left out: the interposer it preloads changes nothing for a
    program that is not a ROS 2 node, and a baseline stored before programs had the key still compares.
    """
    data: dict[str, Any] = scenario.dump(exclude=_NOT_SPEC)
    for process in data.get("processes") or ():
        if isinstance(process, dict) and process.get("callbacks") is True:
            del process["callbacks"]
    return data


def spec_hash(scenario: Scenario) -> str:
    """A short content hash of a resolved cell, to refuse comparing cells that differ."""
    text = json.dumps(spec_json(scenario), sort_keys=True)
    return _digest(text)


def source_hash(data: Any) -> str:
    """A short content hash of a scenario's data as written (comments and layout aside): shards of one run agree on it,
    on machines of any size, since nothing is resolved against a machine yet."""
    return _digest(json.dumps(data, sort_keys=True, default=str))


def expect_hash(cells: list[ResolvedCell]) -> str:
    """A short content hash of the expectations that judge each cell, to refuse resuming a run under changed ones."""
    judged = [(c.id, [c.scenario.expect[i].dump() for i in expectations_for(c.scenario, c.matrix)]) for c in cells]
    return _digest(json.dumps(judged, sort_keys=True))


_NOTE_CELLS = 3  # cell ids named in a problem found in some cells only; the rest are counted


@dataclass(frozen=True)
class MatrixIndex:
    """What expectation selectors are checked against, computed once per file: keys and their values."""

    keys: list[str]
    values: dict[str, dict[str, None]]  # key -> written values, in cell order

    @classmethod
    def of(cls, cells: list[mx.Cell]) -> MatrixIndex:
        values: dict[str, dict[str, None]] = {}
        for cell in cells:
            for key, value in cell.values.items():
                values.setdefault(key, {})[mx.format_value(value)] = None
        return cls(sorted(values), values)


def load_scenario(path: str, machine: lim.MachineLimits | None = None, for_run: bool = True) -> LoadedScenario:
    """Read, validate and expand a scenario file, checked against this machine's limits
    (read here unless given); raise ScenarioError with all problems.

    A file's validity does not depend on the machine: with `for_run` False (`runner validate`,
    `--list`, `import-rtapp`) what this machine lacks (a CPU, memory, threads, deadline bandwidth)
    and what this user may not do (RT priorities, locked memory, priority 99) are warnings.  For a
    run, what the machine lacks is an error (exit 2); rights are left to the run's preflight (exit 3).
    """
    notes: list[str] = []
    doc = _rtapp_document(path, notes, for_run) if path.endswith(".json") else load_file(path)
    loaded = parse_scenario(doc, machine if machine is not None else lim.MachineLimits.read(), for_run)
    loaded.warnings[:0] = [Problem(path, 1, 1, "", note, severity="note") for note in notes]
    return loaded


def _rtapp_document(path: str, notes: list[str], for_run: bool = True) -> Document:
    """A `.json` file is an rt-app workload: convert it as `runner import-rtapp` would, and load the result.

    What did not map exactly is added to `notes`.  Problems the scenario checks find are located
    in the JSON file, at the task, phase or event they came from (`rtapp.Conversion.document`).  A
    runner results file is said to be one, in words for the command that read it (`for_run` False: validate).
    """
    from runner.scenario import rtapp  # only for rt-app files: YAML scenarios do not pay for importing it

    text = rtapp.read(path)
    conversion = rtapp.convert(text, path, "run" if for_run else "validate")
    notes.extend(conversion.notes)
    return conversion.document(path)


def parse_scenario(doc: Document, machine: lim.MachineLimits | None = None, for_run: bool = True) -> LoadedScenario:
    """Validate and expand an already loaded document (pure); `machine` adds that machine's limits
    (what it lacks is a warning unless `for_run`, see load_scenario)."""
    data = doc.data
    if not isinstance(data, dict):
        raise ScenarioError([doc.problem((), f"expected a scenario mapping (name, processes, ...), got {type(data).__name__}")])
    problems: list[Problem] = []
    warnings: list[Problem] = []
    spec = mx.parse(doc, data.get("matrix"), problems)
    mx.check_references(doc, data, spec, problems)
    cells = mx.expand(doc, spec, problems, warnings) if not problems else []
    if problems:
        raise ScenarioError(problems + warnings)

    default_name = os.path.splitext(os.path.basename(doc.file))[0]
    index = MatrixIndex.of(cells)
    written = data.get("expect")
    marks = tuple(doc.mark(("expect", i)) for i in range(len(written))) if isinstance(written, list) else ()
    found: dict[Problem, list[str]] = {}
    resolved: list[ResolvedCell] = []
    checked: dict[str, tuple[Scenario | None, list[Problem]]] = {}
    used = mx.referenced_keys(data)
    for cell in cells:
        # Cells that resolve alike (an axis only selectors use) are checked once: they are those with the same values of
        # the keys the file refers to.  (Keyed by the resolved file itself, 4,096 cells of a 1 MiB file held 4 GiB.)
        key = json.dumps([(k in cell.values, cell.values.get(k)) for k in used])
        if key not in checked:
            raw = mx.substitute(data, cell.values)
            raw.setdefault("name", default_name)
            checked[key] = _check_cell(doc, raw, index, machine, for_run)
        scenario, cell_problems = checked[key]
        if scenario is not None and not any(p.severity == "error" for p in cell_problems):
            resolved.append(ResolvedCell(cell.id, dict(cell.values), scenario, marks))
        for problem in cell_problems:
            found.setdefault(problem, []).append(cell.id)

    for problem, where in found.items():
        if len(cells) > 1 and len(where) < len(cells):
            note = _cells_note(where, len(cells))
            problem = Problem(problem.file, problem.line, problem.col, problem.path, problem.message + note, problem.severity)
        (problems if problem.severity == "error" else warnings).append(problem)
    if problems:
        raise ScenarioError(problems + warnings)
    return LoadedScenario(doc.file, resolved[0].scenario.name, resolved, warnings, doc.data)


def _check_cell(
    doc: Document, raw: dict[str, Any], index: MatrixIndex, machine: lim.MachineLimits | None, for_run: bool = True
) -> tuple[Scenario | None, list[Problem]]:
    """Validate one resolved cell: the model, cross-field checks, ceilings and (if given) this machine's limits."""
    cell_problems: list[Problem] = []
    for path, expr in mx.unresolved(raw):
        cell_problems.append(doc.problem(path, f"'${{{{ {expr} }}}}' has no value in this cell"))
    context = validation_context(machine)
    try:
        scenario = Scenario.parse(raw, context)
    except Invalid as exc:
        cell_problems.extend(problems_from(exc, doc, raw))
        cell_problems.extend(_partial_cross_checks(doc, raw, index, context))
        return None, cell_problems
    cell_problems.extend(_cross_checks(doc, scenario.processes, list(enumerate(scenario.expect)), index, scenario.resources))
    late = program.never_released(scenario.processes, scenario.duration)
    cell_problems.extend(doc.problem(written_path(doc.data, path), message) for path, message in late)
    findings = lim.check(scenario, machine) if machine is not None else lim.static_check(scenario)
    for f in findings:
        if f.right and for_run:
            continue  # the run's preflight tries each right on the kernel and says how to grant it (exit 3)
        warn = (f.elsewhere or f.right) and not for_run
        message = f.message + ("; the file is valid, but it cannot run here" if warn and f.elsewhere else "")
        cell_problems.append(doc.problem(written_path(doc.data, f.path), message, severity="warning" if warn else "error"))
    return scenario, cell_problems


def validation_context(machine: lim.MachineLimits | None) -> dict[str, Any] | None:
    """What the models resolve `count: cpus` and `pin: each` against: the machine's CPUs, when known."""
    return {CPUS_CONTEXT: machine.cpus} if machine is not None and machine.cpus else None


def _cells_note(where: list[str], total: int) -> str:
    """` (in cell X)` / ` (in 3 of 8 cells: a; b; c)` / `(in 900 of 4096 cells: a; b; c; and 897 more)`."""
    if len(where) == 1:
        return f" (in cell {where[0]})"
    named = "; ".join(where[:_NOTE_CELLS])
    more = f"; and {len(where) - _NOTE_CELLS} more" if len(where) > _NOTE_CELLS else ""
    return f" (in {len(where)} of {total} cells: {named}{more})"


def _partial_cross_checks(doc: Document, raw: dict[str, Any], index: MatrixIndex, context: dict[str, Any] | None) -> list[Problem]:
    """Cross-field checks on the parts that did validate, so one bad field does not hide the rest.

    Each process is taken on its own: those that validate are checked.  While one does not, an
    expectation is judged only when it names a valid process (`process/thread`): a bare thread
    name may be one of the invalid process's, written or numbered (`count`, `pin: each`), or a
    program's.  References between processes (resources' users) wait for every process to be valid.
    """
    written = raw.get("processes")
    if not isinstance(written, list):
        return []
    processes: list[AnyProcess] = []
    at: list[int] = []  # where each valid process is written
    invalid: set[str] = set()  # the names the invalid processes are written with
    for i, item in enumerate(written):
        try:
            processes.append(parse(AnyProcess, item, context))
            at.append(i)
        except Invalid:
            if isinstance(item, dict) and isinstance(item.get("name"), str):
                invalid.add(item["name"])
    expectations = []
    for i, item in enumerate(raw.get("expect") or [] if isinstance(raw.get("expect"), list) else []):
        try:
            expectations.append((i, Expectation.parse(item)))
        except Invalid:
            continue
    try:
        resources: dict[str, Resource] | None = parse(dict[str, Resource], raw.get("resources") or {})
    except Invalid:
        resources = None  # its own problems are reported; references to it cannot be checked
    complete = len(processes) == len(written)
    return _cross_checks(doc, processes, expectations, index, resources if complete else None, at, None if complete else frozenset(invalid))


def _cross_checks(
    doc: Document,
    processes: list[AnyProcess],
    expectations: list[tuple[int, Expectation]],
    index: MatrixIndex,
    resources: dict[str, Resource] | None,
    at: list[int] | None = None,
    invalid: frozenset[str] | None = None,
) -> list[Problem]:
    """Checks that span several fields: unique names, expectation targets and selectors, programs' resources, deadline rules.

    `at`: where each of `processes` is written, when they are the valid ones of a list; `invalid`:
    given when some process did not validate, the names those are written with.
    """
    out: list[Problem] = []

    def written(path: tuple[Any, ...]) -> tuple[Any, ...]:
        if at is not None and path[:1] == ("processes",):
            path = ("processes", at[path[1]], *path[2:])
        return written_path(doc.data, path)

    if resources is not None:
        out.extend(doc.problem(written(path), message) for path, message in program.reference_problems(processes, resources))
    out.extend(doc.problem(written(path), message) for path, message in program.deadline_problems(processes))
    out.extend(doc.problem(written(path), message) for path, message in program.spawn_problems(processes))
    seen: set[str] = set()
    programs = {p.name for p in processes if isinstance(p, ProgramSpec)}
    for i, proc in enumerate(processes):
        if isinstance(proc, ProgramSpec) and proc.until is Until.EXIT and len(programs) < len(processes):
            out.append(
                doc.problem(
                    written(("processes", i, "until")),
                    "until: exit ends the cell when the program exits, but the runner's own processes run for the whole duration; "
                    "run the load as background (hogs, commands) or use until: end",
                )
            )
        if proc.name in seen:
            twice = f"process name {proc.name!r} is used twice; use instances: N for copies"
            out.append(doc.problem(written(("processes", i, "name")), twice))
        seen.add(proc.name)
    planned = [t for proc in workers(processes) for t in plan_process(proc, Settings())]
    names: dict[str, list[str]] = {}
    for t in planned:
        names.setdefault(t.process, []).extend(n for n in {t.name, t.spec_name} if n not in names.get(t.process, []))
    every = sorted({n for group in names.values() for n in group})
    keys = index.keys
    ros = [p.name for p in processes if isinstance(p, ProgramSpec) and p.callbacks]
    for i, exp in expectations:
        path: tuple[Any, ...] = ("expect", i)
        targets = match_threads(planned, exp.thread)
        process, sep, thread = exp.thread.rpartition("/")
        if exp.callback:
            if not ros and invalid is None:
                out.append(doc.problem(path + ("callback",), _NO_CALLBACKS))
            unmeasurable = ""
        elif invalid is not None and (not sep or process in invalid) and not (sep and process in programs):
            continue  # may name threads of a process that did not validate (its problems are reported)
        elif process in programs if sep else not targets and programs:
            # a program's threads are known only once it runs (one that never appears fails its expectation then),
            # but which figures a program's thread has is known now
            unmeasurable = measure_problem(exp, [], PROGRAM_THREAD)
        elif sep and process not in names:
            out.append(doc.problem(path + ("thread",), f"no process named {process!r}{did_you_mean(process, names)}"))
            unmeasurable = ""
        elif not targets:
            pool = names.get(process, []) if sep else every
            out.append(
                doc.problem(
                    path + ("thread",), f"no thread named {thread!r}{did_you_mean(thread, pool)}; threads: {', '.join(sorted(set(pool)))}"
                )
            )
            unmeasurable = ""
        else:
            unmeasurable = measure_problem(exp, targets)
        if unmeasurable:
            out.append(doc.problem(path + ("metric",), unmeasurable))
        for key, wanted in exp.cells.items():
            if key not in keys:
                known = ", ".join(keys) if keys else "none (there is no matrix)"
                out.append(
                    doc.problem(path + ("cells", key), f"{key!r} is not a matrix key{did_you_mean(key, keys)}; keys: {known}", key=True)
                )
                continue
            if wanted == []:
                why = f"{key}: [] selects no cell, so the expectation would check nothing; values: {', '.join(sorted(index.values[key]))}"
                out.append(doc.problem(path + ("cells", key), why))
                continue
            for value in wanted if isinstance(wanted, list) else [wanted]:
                if mx.format_value(value) not in index.values[key]:
                    values = sorted(index.values[key])
                    out.append(
                        doc.problem(path + ("cells", key), f"{key}={mx.format_value(value)} matches no cell; values: {', '.join(values)}")
                    )
    return out


_NO_CALLBACKS = (
    "no program of the scenario has ROS 2 callbacks to judge: a callback: expectation needs a command: program "
    "with callbacks on (the default)"
)


def measure_problem(exp: Expectation, targets: list[PlannedThread], kind: ThreadKind | None = None) -> str:
    """Why `exp` can never be met on the threads it names, or "": none of them can have its figure at all.

    `targets` are the runner's own threads it names, known from the file: it judges those that can
    have the figure (a ROS process names its helper threads after itself, so `minimal_schedul` names
    its periodic main thread and its sleeping helpers, and a latency judges the main thread), and is
    refused when none can.  `kind` (a program's thread) stands for threads known only once the cell
    runs, each of which a run judges: refused when that kind of thread cannot have the figure.
    """
    fig = metric_figure(exp.metric)
    if kind is None:
        if not targets or any(has(thread_kind(t), fig) for t in targets):
            return ""
        kind = thread_kind(targets[0])
    elif has(kind, fig):
        return ""
    return f"{exp.metric.value} {measured_how(fig)}, but {exp.thread!r} is {kind.words}, which has {figures_of(kind)}"
