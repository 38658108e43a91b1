"""Threads spread over the CPUs as cyclictest spreads them: `count: cpus`, `pin: each`, `priospread`, `distance`.

Pure: the machine's CPUs are given (a fake 4-CPU machine), so the expansion is the same on
every machine the tests run on; the kernel test of where the threads really ran is in
test_kernel.py.
"""

from __future__ import annotations

import os

import pytest
from conftest import SCENARIOS, run_cli

from runner.errors import ScenarioError
from runner.scenario import limits as lim
from runner.scenario.listing import render_cell
from runner.scenario.loader import LoadedScenario, parse_scenario, spec_json
from runner.scenario.matching import match_threads
from runner.scenario.model import Policy, ProcessSpec, ThreadSpec
from runner.scenario.plan import Settings, plan_scenario
from runner.scenario.yamlsource import load_file, load_text

FOUR = lim.MachineLimits(cpus=(0, 1, 2, 3))
TWO = lim.MachineLimits(cpus=(0, 1))


def scenario(thread: str, machine: lim.MachineLimits = FOUR) -> LoadedScenario:
    """A one-process scenario whose only thread spec is `thread` (a flow mapping), loaded as on `machine`."""
    text = f"name: x\nprocesses:\n  - name: cyclictest\n    threads:\n      - {thread}\n"
    return parse_scenario(load_text(text, "s.yaml"), machine)


def problems(thread: str, machine: lim.MachineLimits = FOUR) -> list[str]:
    with pytest.raises(ScenarioError) as caught:
        scenario(thread, machine)
    return [str(p) for p in caught.value.problems]


def measured(loaded: LoadedScenario) -> list[tuple[str, Policy, int, object, int]]:
    """(name, policy, priority, cpus, period) of every created thread, as the plan expects them to end up."""
    threads = plan_scenario(loaded.cells[0].scenario, Settings())[1:]
    return [(t.name, t.settings.policy, t.settings.priority, t.settings.cpus, getattr(t.work, "period", 0)) for t in threads]


CYCLICTEST = (
    "{name: cyclic, count: cpus, pin: each, sched: fifo:80, priospread: true, distance: 500us, work: {kind: periodic, period: 1ms}}"
)


def test_cyclictest_t_a_priospread_d_one_thread_per_cpu_each_pinned_with_its_priority_and_period():
    assert measured(scenario(CYCLICTEST)) == [
        ("cyclic-0", Policy.FIFO, 80, (0,), 1_000_000),
        ("cyclic-1", Policy.FIFO, 79, (1,), 1_500_000),
        ("cyclic-2", Policy.FIFO, 78, (2,), 2_000_000),
        ("cyclic-3", Policy.FIFO, 77, (3,), 2_500_000),
    ]


def test_the_count_is_the_machines():
    assert [row[0] for row in measured(scenario(CYCLICTEST, TWO))] == ["cyclic-0", "cyclic-1"]
    spec = scenario(CYCLICTEST, TWO).cells[0].scenario.processes[0].threads[0]
    assert (spec.count, spec.cpus, spec.per_cpu, spec.machine_cpus) == (2, (0, 1), True, (0, 1))


def test_the_resolved_count_and_cpus_are_part_of_the_cells_spec():
    """A 2-CPU and a 4-CPU run of the same file are different cells: comparing them is refused."""
    two, four = scenario(CYCLICTEST, TWO).cells[0], scenario(CYCLICTEST).cells[0]
    assert two.spec_hash != four.spec_hash
    assert two.scenario.dump()["processes"][0]["threads"][0]["count"] == 2


@pytest.mark.parametrize("name", ["policy_matrix", "memory_lock", "fifo80"])
def test_a_spec_that_does_not_spread_hashes_as_if_spreading_did_not_exist(name):
    """Unused pin, priospread and distance stay out of a cell's spec, so the spec hash results record (and
    `compare` and `--resume` check) is the one the same file had before they existed."""
    loaded = parse_scenario(load_file(os.path.join(SCENARIOS, f"{name}.yaml")), TWO)
    for cell in loaded.cells:
        threads = [t for proc in spec_json(cell.scenario)["processes"] for t in proc["threads"]]
        assert threads and all(set(t) == {"name", "count", "inherit", "sched", "cpus", "work"} for t in threads)


def test_a_spread_is_part_of_the_spec_when_used():
    spec = scenario(CYCLICTEST).cells[0].scenario.dump()["processes"][0]["threads"][0]
    assert (spec["count"], spec["cpus"], spec["pin"], spec["priospread"], spec["distance"]) == (4, "0-3", "each", True, "500us")
    plain = scenario("{name: w, count: 2}").cells[0].scenario.dump()["processes"][0]["threads"][0]
    assert not {"pin", "priospread", "distance"} & set(plain)


def test_a_cpus_set_gives_one_thread_per_cpu_of_the_set_named_by_its_cpu():
    rows = measured(scenario("{name: cyclic, count: cpus, cpus: 2-3, pin: each, sched: fifo:80, work: {kind: periodic, period: 1ms}}"))
    assert [(name, cpus, prio) for name, _, prio, cpus, _ in rows] == [("cyclic-2", (2,), 80), ("cyclic-3", (3,), 80)]


def test_a_mask_is_a_cpus_set_too():
    rows = measured(scenario("{name: c, count: cpus, cpus: 0b1010, pin: each}"))
    assert [(name, cpus) for name, _, _, cpus, _ in rows] == [("c-1", (1,)), ("c-3", (3,))]


def test_count_cpus_without_pin_numbers_the_threads_and_leaves_their_affinity():
    rows = measured(scenario("{name: w, count: cpus, sched: rr:10}"))
    assert [(name, cpus, prio) for name, _, prio, cpus, _ in rows] == [(f"w-{i}", None, 10) for i in range(4)]
    rows = measured(scenario("{name: w, count: cpus, cpus: 1-2}"))
    assert [(name, cpus) for name, _, _, cpus, _ in rows] == [("w-0", (1, 2)), ("w-1", (1, 2))], "one per CPU of the set, not pinned"


def test_an_explicit_count_with_pin_each_takes_the_first_cpus():
    rows = measured(scenario("{name: c, count: 2, pin: each}"))
    assert [(name, cpus) for name, _, _, cpus, _ in rows] == [("c-0", (0,)), ("c-1", (1,))]
    rows = measured(scenario("{name: c, pin: each, cpus: [3]}"))
    assert [(name, cpus) for name, _, _, cpus, _ in rows] == [("c-3", (3,))], "a pinned thread is named by its CPU even alone"


def test_priospread_and_distance_without_pinning():
    rows = measured(scenario("{name: c, count: 3, sched: fifo:3, priospread: true, distance: 1ms, work: {kind: periodic, period: 1ms}}"))
    assert [(name, prio, period) for name, _, prio, _, period in rows] == [
        ("c-0", 3, 1_000_000),
        ("c-1", 2, 2_000_000),
        ("c-2", 1, 3_000_000),
    ]


def test_priospread_below_1_is_an_error_at_its_line():
    assert problems("{name: c, count: 4, sched: fifo:3, priospread: true}") == [
        "s.yaml:5:56: processes[0].threads[0].priospread: priospread takes thread c-3 to priority 0 (thread i runs at "
        "fifo:3 minus i) and RT priorities stop at 1; 4 threads need fifo:4 or more, or a lower count"
    ]


def test_priospread_below_1_with_count_cpus_names_the_machines_cpus():
    text = "name: x\nprocesses:\n  - name: cyclictest\n    threads:\n      - name: cyclic\n        count: cpus\n"
    text += "        sched: fifo:2\n        priospread: true\n"
    with pytest.raises(ScenarioError) as caught:
        parse_scenario(load_text(text, "s.yaml"), FOUR)
    assert [str(p) for p in caught.value.problems] == [
        "s.yaml:8:21: processes[0].threads[0].priospread: priospread takes thread cyclic-3 to priority -1 (thread i runs at "
        "fifo:2 minus i) and RT priorities stop at 1; 4 threads (count: cpus, one per CPU: the 4 CPUs the runner may use "
        "(0-3)) need fifo:4 or more, or a lower count"
    ]
    assert parse_scenario(load_text(text, "s.yaml"), TWO).cells, "the same file is valid on a 2-CPU machine"


def test_priospread_needs_an_rt_priority_of_its_own():
    for sched in ("", ", sched: other", ", sched: batch"):
        (found,) = problems(f"{{name: c, count: 2, priospread: true{sched}}}")
        assert found.startswith("s.yaml:5:41: processes[0].threads[0].priospread: priospread lowers the RT priority by one per thread")
        assert found.endswith("it needs this thread's own sched: fifo:N or rr:N")


def test_pin_each_refuses_more_threads_than_cpus():
    assert problems("{name: c, count: 3, cpus: 2-3, pin: each}") == [
        "s.yaml:5:45: processes[0].threads[0].pin: pin: each gives every thread a CPU of its own, but count 3 is more than "
        "the 2 CPUs of cpus 2-3; lower count, or write count: cpus for one thread per CPU"
    ]
    (found,) = problems("{name: c, count: 3, pin: each}", TWO)
    assert "count 3 is more than the 2 CPUs the runner may use (0-1)" in found


def test_pin_each_on_cpus_this_machine_lacks_is_refused_by_the_machine_check():
    (found,) = problems("{name: c, count: cpus, cpus: 2-3, pin: each}", TWO)
    assert found == "s.yaml:5:38: processes[0].threads[0].cpus: CPUs 2-3 are not available on this machine (the runner may use 0-1)"


def test_distance_needs_periodic_work_and_a_period_in_range():
    (found,) = problems("{name: c, count: 2, distance: 1ms, work: spin}")
    assert found.startswith("s.yaml:5:39: processes[0].threads[0].distance: distance spaces the periods of periodic work apart")
    assert "this thread's work is spin" in found
    (found,) = problems("{name: c, count: 3, distance: 40m, work: {kind: periodic, period: 1ms}}")
    assert found.startswith("s.yaml:5:39: processes[0].threads[0].distance: distance 40m gives thread c-2 a period of")
    assert found.endswith("at most 1h, lower distance or count")


def test_unknown_pin_says_what_is_expected():
    (found,) = problems("{name: c, pin: every}")
    assert found == "s.yaml:5:24: processes[0].threads[0].pin: 'every' is not valid; expected one of: each"


def test_names_by_cpu_must_fit_the_kernels_15_bytes():
    (found,) = problems("{name: cyclictest_xy, count: cpus, cpus: 10-11, pin: each}", lim.MachineLimits(cpus=tuple(range(12))))
    assert "name 'cyclictest_xy-10' is 16 bytes" in found


def test_expectations_name_every_thread_of_the_spec_or_one():
    planned = plan_scenario(scenario(CYCLICTEST).cells[0].scenario, Settings())
    assert [t.name for t in match_threads(planned, "cyclic")] == ["cyclic-0", "cyclic-1", "cyclic-2", "cyclic-3"]
    assert [t.name for t in match_threads(planned, "cyclictest/cyclic-2")] == ["cyclic-2"]


def test_the_worker_is_told_each_threads_own_cpu_priority_and_period():
    from runner.run.samples import Layout
    from runner.run.wiring import process_spec

    sc = scenario(CYCLICTEST).cells[0].scenario
    threads = plan_scenario(sc, Settings())
    spec = process_spec(threads, sc, Layout(len(threads), 16), {id(t): n for n, t in enumerate(threads)}, (0, 1, 2, 3))
    assert [(t["name"], t["cpus"], t["sched"], t["work"][1]) for t in spec["threads"]] == [
        ("cyclic-0", [0], [1, 80, None, None], 1_000_000),
        ("cyclic-1", [1], [1, 79, None, None], 1_500_000),
        ("cyclic-2", [2], [1, 78, None, None], 2_000_000),
        ("cyclic-3", [3], [1, 77, None, None], 2_500_000),
    ]


def test_list_shows_each_thread_and_where_the_count_came_from():
    text = render_cell(scenario(CYCLICTEST).cells[0], Settings(), (0, 1, 2, 3))
    assert "cyclic-3    fifo:77        0  3       own         periodic 2.5ms" in text
    assert (
        "cyclic: 4 threads (count: cpus, one per CPU: the 4 CPUs the runner may use (0-3)), each pinned to its own CPU "
        "and named by it, priorities fifo:80 down to fifo:77 (priospread), periods 1ms to 2.5ms (distance 500us)"
    ) in text


def test_validate_shows_the_expansion_on_this_machine(write_scenario):
    path = write_scenario(f"name: x\nprocesses:\n  - name: cyclictest\n    threads:\n      - {CYCLICTEST.replace('fifo:80', 'fifo:98')}\n")
    outcome = run_cli("validate", path)
    cpus = sorted(os.sched_getaffinity(0))
    assert outcome.code == 0, outcome.err
    lines = outcome.out.splitlines()
    assert lines[0] == f"{path}: ok (1 cell)"
    assert lines[1].startswith(f"  cyclictest/cyclic: {len(cpus)} thread")
    assert [line.split() for line in lines[2:]] == [
        [f"cyclic-{cpu}", "CPU", str(cpu), f"fifo:{98 - i}", "periodic", f"{1 + i * 0.5:g}ms"] for i, cpu in enumerate(cpus)
    ]


def test_validate_says_nothing_more_for_plain_threads(write_scenario):
    path = write_scenario("name: x\nprocesses:\n  - name: app\n    threads: [{name: w, count: 3}]\n")
    assert run_cli("validate", path).out == f"{path}: ok (1 cell)\n"


def test_validate_names_the_cells_where_the_expansion_differs(write_scenario):
    text = "name: x\nmatrix: {prio: [80, 40]}\nprocesses:\n  - name: app\n    threads:\n"
    text += "      - {name: c, count: 2, sched: 'fifo:${{ matrix.prio }}', priospread: true}\n"
    out = run_cli("validate", write_scenario(text)).out.splitlines()
    assert "  in cell prio=80:" in out and "  in cell prio=40:" in out
    assert any("fifo:39" in line for line in out)


def test_hogs_and_threads_resolve_count_cpus_against_the_same_cpus():
    text = "name: x\nprocesses:\n  - name: app\n    threads: [{name: w, count: cpus}]\nbackground:\n  hogs: [{count: cpus}]\n"
    sc = parse_scenario(load_text(text, "s.yaml"), lim.MachineLimits(cpus=(0, 1, 2, 3, 4))).cells[0].scenario
    assert sc.processes[0].threads[0].count == 5 and sc.background.hogs[0].count == 5


def test_without_a_machine_the_model_falls_back_to_the_runners_affinity():
    spec = ThreadSpec.parse({"name": "c", "count": "cpus", "pin": "each"})
    assert spec.cpus == tuple(sorted(os.sched_getaffinity(0))) and spec.count == len(spec.cpus)
    proc = ProcessSpec.parse({"name": "p", "threads": [{"name": "c", "count": "cpus"}]}, {"cpus": (5, 6, 7)})
    assert proc.threads[0].count == 3


def test_the_shipped_cyclictest_scenario_is_one_pinned_thread_per_cpu():
    from runner.scenario.loader import load_scenario

    loaded = load_scenario(os.path.join(SCENARIOS, "cyclictest_smp.yaml"))
    cpus = tuple(sorted(os.sched_getaffinity(0)))
    rows = measured(loaded)
    assert [(name, policy, prio, c) for name, policy, prio, c, _ in rows] == [
        (f"cyclic-{cpu}", Policy.FIFO, 80 - i, (cpu,)) for i, cpu in enumerate(cpus)
    ]
    assert {period for *_, period in rows} == {1_000_000}
