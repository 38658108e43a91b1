"""Every shipped scenario validates, lists, follows its seed example's settings, and satisfies the JSON Schema."""

from __future__ import annotations

import glob
import json
import os

import jsonschema
import pytest
from conftest import REPO, SCENARIOS, run_cli

from runner.scenario.loader import load_scenario
from runner.scenario.matching import expectations_for, match_threads
from runner.scenario.model import PhasesWork, Policy, ProgramSpec
from runner.scenario.plan import Settings, plan_scenario
from runner.scenario.schema import scenario_schema
from runner.scenario.yamlsource import load_file

SHIPPED = sorted(glob.glob(os.path.join(SCENARIOS, "*.yaml")))
NAMES = {os.path.basename(p)[:-5] for p in SHIPPED}


def test_every_example_of_the_issue_is_shipped():
    assert {
        "fifo80",
        "rr80",
        "other",
        "middleware_threads",
        "spin_thread",
        "callback_group",
        "real_time_executor",
        "cpu_affinity_main_thread",
        "cpu_affinity_middleware_threads",
        "cpu_affinity_mask",
        "memory_lock",
        "policy_matrix",
    } <= NAMES


# scenarios that reproduce another tool's command rather than a seed program: they keep that tool's
# timing (cyclictest's 1 ms wake-ups with no work, a short run), not the seed's proportion
TOOLS = {"cyclictest_smp": "cyclictest"}
# scenarios of programs (kind: phases) after rt-app's workloads: locks, deadline, chains, phases; each is run
# for real by tests/test_kernel_programs.py, which holds it to the effect its description states
PROGRAMS = {"priority_inversion", "deadline", "pipeline", "phases", "spawn"}
# scenarios that run a program of the user's (command:), measured from outside, and the program each runs: README's
# "Measure your own program"; tests/test_kernel_external.py runs it for real (skipped, saying so, without the program)
COMMANDS = {"own_program": "cyclictest"}


@pytest.mark.parametrize("path", SHIPPED, ids=os.path.basename)
def test_shipped_scenario_validates_and_lists(path):
    loaded = load_scenario(path)
    assert not loaded.warnings
    outcome = run_cli(path, "--list")
    assert outcome.code == 0, outcome.err
    for cell in loaded.cells:
        assert f"cell {cell.id}" in outcome.out
    if loaded.name in TOOLS:
        assert loaded.description.startswith(TOOLS[loaded.name] + " "), "says which command it reproduces"
        for cell in loaded.cells:
            assert cell.scenario.duration <= 2_000_000_000, "a short run: it is run for real by the kernel tests"
            assert any(hasattr(t.work, "period") for t in plan_scenario(cell.scenario, Settings()))
        return
    if loaded.name in COMMANDS:
        assert loaded.description.startswith(COMMANDS[loaded.name] + " "), "says which command it runs"
        for cell in loaded.cells:
            sc = cell.scenario
            commands = [p for p in sc.processes if isinstance(p, ProgramSpec)]
            assert [p.command[0] for p in commands] == [COMMANDS[loaded.name]], "runs the program it names, and only it"
            assert sc.duration <= 2_000_000_000, "a short run: it is run for real by the kernel tests"
            assert all(p.cpus is None or max(p.cpus) < 2 for p in commands), "must run on a 2-CPU machine"
            assert sc.background.hogs and sc.expect, "contention, and an expectation to judge the program by"
        return
    if loaded.name in PROGRAMS:
        for cell in loaded.cells:
            threads = plan_scenario(cell.scenario, Settings())
            assert any(isinstance(t.work, PhasesWork) and t.period for t in threads), "a program with a timer: callbacks to measure"
            assert cell.scenario.duration <= 5_000_000_000
            for t in threads:
                assert t.settings.cpus is None or max(t.settings.cpus) < 2, "must run on a 2-CPU machine"
        return
    assert "ros2-realtime-examples" in loaded.description or loaded.name == "policy_matrix"
    for cell in loaded.cells:
        sc = cell.scenario
        assert sc.duration == 10_000_000_000
        periodic = [t for t in plan_scenario(sc, Settings()) if hasattr(t.work, "period")]
        assert periodic, "a scenario without callbacks measures nothing"
        for t in periodic:
            assert t.work.period <= 200_000_000, "a 10s run must give at least 50 callbacks"
            assert t.work.burn * 10 == t.work.period * 4, "the seed's proportion: burn 40% of the period"
        for t in plan_scenario(sc, Settings()):
            assert t.settings.cpus is None or max(t.settings.cpus) < 2, "must run on a 2-CPU machine"
        assert sc.background.hogs, "contention is what makes SCHED_OTHER lose"


@pytest.mark.parametrize("path", SHIPPED, ids=os.path.basename)
def test_shipped_scenario_satisfies_the_schema(path):
    jsonschema.validate(load_file(path).data, scenario_schema())


def test_schema_file_in_the_repository_is_current():
    with open(os.path.join(REPO, "runner.schema.json")) as handle:
        assert json.load(handle) == scenario_schema(), "regenerate with: runner schema > runner.schema.json"


def test_schema_command_prints_the_schema():
    outcome = run_cli("schema")
    assert outcome.code == 0 and json.loads(outcome.out)["title"] == "runner scenario"


def test_schema_rejects_what_validation_rejects():
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"name": "x", "processes": [{"name": "a", "polcy": 1}]}, scenario_schema())


# The threads of shipped scenarios whose missed releases are part of what the scenario shows (an OTHER thread
# under load, a FIFO load that yields to DEADLINE), by cell: each must say in the file what it accepts.
SHOWS_MISSES = {
    "pipeline": {("sched=other", "sensor")},
    "phases": {("default", "mover")},
    "deadline": {("sched=deadline:4ms/10ms/10ms", "burner"), ("sched=other", "burner"), ("sched=other", "worker")},
}


@pytest.mark.parametrize("name", sorted(SHOWS_MISSES))
def test_a_shipped_scenario_states_the_misses_it_shows_and_accepts_none_elsewhere(name):
    """A thread whose misses are the scenario's point has its own bound on missed_releases, so a busy machine
    neither fails the scenario for its effect nor lets the claim vanish; every other thread with callbacks
    keeps "every release served" (the implicit rule, or an explicit max 0): the real-time ones are never loosened."""
    loaded = load_scenario(os.path.join(SCENARIOS, f"{name}.yaml"))
    accepting: set[tuple[str, str]] = set()
    for cell in loaded.cells:
        threads = plan_scenario(cell.scenario, Settings())
        for i in expectations_for(cell.scenario, cell.matrix):
            exp = cell.scenario.expect[i]
            if exp.metric.value not in ("missed_releases", "overruns") or exp.max == 0:
                continue
            matched = match_threads(threads, exp.thread)
            assert matched and all(t.has_callbacks for t in matched), (cell.id, exp.thread)
            assert exp.max is not None or exp.min, "a bound: some misses accepted, not any number"
            accepting |= {(cell.id, t.spec_name) for t in matched}
    assert accepting == SHOWS_MISSES[name]


def expected_rows(name: str) -> list[tuple[str, Policy, int]]:
    sc = load_scenario(os.path.join(SCENARIOS, f"{name}.yaml")).cells[0].scenario
    return [(t.name, t.settings.policy, t.settings.priority) for t in plan_scenario(sc, Settings())]


def test_seed_inheritance_patterns_are_what_the_plan_says():
    main = expected_rows("fifo80")
    assert main[0][1:] == (Policy.FIFO, 80) and all(p is Policy.OTHER for _, p, _ in main[1:]) and len(main) == 10
    assert expected_rows("rr80")[0][1:] == (Policy.RR, 80)
    assert all(r[1:] == (Policy.FIFO, 80) for r in expected_rows("middleware_threads"))
    spin = expected_rows("spin_thread")
    assert len(spin) == 11 and spin[-1][1:] == (Policy.FIFO, 80) and all(p is Policy.OTHER for _, p, _ in spin[:-1])
    assert [r[0] for r in expected_rows("real_time_executor") if r[1] is Policy.FIFO] == ["minimal_sub2"]
    assert [r[0] for r in expected_rows("callback_group") if r[1] is Policy.FIFO] == ["rt_sub"]


@pytest.mark.parametrize("name", ["policy_matrix", "memory_lock"])
def test_baselines_recorded_by_earlier_versions_still_compare(name):
    """A new scenario key left at its default must not change a cell's spec hash, or every stored baseline is refused."""
    with open(os.path.join(REPO, "tests", "data", name, "results.json")) as handle:
        stored = {c["id"]: c["spec_hash"] for c in json.load(handle)["cells"]}
    ours = {c.id: c.spec_hash for c in load_scenario(os.path.join(SCENARIOS, f"{name}.yaml")).cells}
    assert stored == {cell: ours[cell] for cell in stored}


def test_every_shipped_cells_spec_hash_is_as_recorded():
    """The spec hash of every cell of the shipped and corpus scenarios, on a 2-CPU machine, is what earlier versions stored.

    tests/golden/spec_hashes.json was written by the runner whose scenario models were pydantic's; the
    models' own dump (runner.scenario.typed) must give the same JSON, or every stored baseline is refused.
    A change that means to change a spec (a new scenario, an edited one) rewrites the file with UPDATE_GOLDEN=1, and
    its commit says so: a cell whose hash changes no longer compares with the baselines stored before.
    """
    from runner.scenario.limits import MachineLimits
    from runner.scenario.loader import parse_scenario

    golden = os.path.join(REPO, "tests", "golden", "spec_hashes.json")
    machine = MachineLimits(cpus=(0, 1), online=(0, 1))
    paths = sorted(glob.glob(os.path.join(SCENARIOS, "*.yaml")) + glob.glob(os.path.join(REPO, "tests", "valid", "*.yaml")))
    ours = {}
    for path in paths:
        loaded = parse_scenario(load_file(path), machine, for_run=False)
        ours[os.path.relpath(path, REPO)] = {c.id: c.spec_hash for c in loaded.cells}
    if os.environ.get("UPDATE_GOLDEN") == "1":
        with open(golden, "w") as handle:
            handle.write(json.dumps(ours, indent=1, sort_keys=True) + "\n")
    with open(golden) as handle:
        assert ours == json.load(handle), "a spec hash changed; rerun with UPDATE_GOLDEN=1 if intended"


def test_a_programs_callbacks_off_changes_its_spec_hash_and_the_default_does_not(tmp_path):
    """`callbacks: on` is every program's default and leaves the spec hash as stored before the key existed; `off` is another run."""
    own = open(os.path.join(SCENARIOS, "own_program.yaml")).read()
    written = {}
    for name, extra in (("default", ""), ("on", "    callbacks: on\n"), ("off", "    callbacks: off\n")):
        path = tmp_path / f"{name}.yaml"
        path.write_text(own.replace("    cpus: 0 ", extra + "    cpus: 0 ", 1))
        written[name] = load_scenario(str(path)).cells[0].spec_hash
    assert written["default"] == written["on"] != written["off"]


ROS2 = sorted(glob.glob(os.path.join(SCENARIOS, "ros2", "*.yaml")))
SEED_EXECUTABLES = {  # ros2-realtime-examples' minimal_scheduling programs, and the nodes whose callbacks each judges
    "minimal_scheduling_main_thread": {"minimal_publisher"},
    "minimal_scheduling_middleware_threads": {"minimal_publisher"},
    "minimal_scheduling_spin_thread": {"minimal_publisher"},
    "minimal_scheduling_callback_group": {"minimal_sub", "minimal_pub"},
    "minimal_scheduling_real_time_executor": {"minimal_sub1", "minimal_sub2", "minimal_pub"},
}


def test_every_seed_program_of_minimal_scheduling_ships_as_a_ros2_scenario():
    assert {os.path.basename(p)[:-5] for p in ROS2} == set(SEED_EXECUTABLES)


@pytest.mark.parametrize("path", ROS2, ids=os.path.basename)
def test_a_ros2_scenario_runs_the_seeds_own_program_and_judges_its_callbacks(path):
    """`ros2 run minimal_scheduling X` unmodified, measured callback by callback: README's "Your ROS 2 node"."""
    executable = os.path.basename(path)[:-5]
    loaded = load_scenario(path)
    assert not loaded.warnings
    assert loaded.description.startswith(f"ros2 run minimal_scheduling {executable}")
    assert run_cli(path, "--list").code == 0
    for cell in loaded.cells:
        sc = cell.scenario
        (program,) = sc.processes
        assert isinstance(program, ProgramSpec) and program.callbacks
        assert program.command[:4] == ["ros2", "run", "minimal_scheduling", executable]
        assert program.sched is None, "the seed applies its own --sched and --priority, as its README runs it"
        assert sc.background.hogs, "something for SCHED_OTHER to lose against"
        judged = [sc.expect[i] for i in expectations_for(sc, cell.matrix)]
        assert judged and all(e.callback and not e.thread for e in judged), "judged by its callbacks, not its threads"
        assert {e.callback.split("/")[0] for e in judged} <= SEED_EXECUTABLES[executable]
        switches = [e for e in judged if e.metric.value == "involuntary.per_callback_mean"]
        assert switches, "the seed's own figure"
