"""The scenario as the native core takes it (run/wiring.py): worker specs, rings and hogs, without a process or RT rights.

What a worker is told decides what it measures: a thread told another period, ring or set of
CPUs measures something else without any error.  These are read from the specs alone; the
kernel tests check that workers do what the specs say.
"""

from __future__ import annotations

from runner.run import _probe, wiring
from runner.run.wiring import RING_MAX, hog_specs, process_spec, ring_capacity, work_tuple, worker_layout
from runner.scenario.model import Overrun, PhasesWork, ResourceKind, Samples, Scenario, SleepWork, SpinWork
from runner.scenario.plan import PlannedThread, Settings, plan_scenario

MACHINE = (7, 9)  # CPUs no test machine's runner is limited to: seen in a spec, they came from the argument, not from the machine


def _scenario(**extra: object) -> Scenario:
    base: dict[str, object] = {
        "name": "s",
        "processes": [
            {
                "name": "app",
                "start": "in_order",
                "main": {"sched": "fifo:80", "work": {"kind": "periodic", "period": "1ms", "burn": "100us"}},
                "threads": [
                    {"name": "fast", "sched": "fifo:70", "cpus": "1", "work": {"kind": "periodic", "period": "2ms"}},
                    {"name": "idle"},
                    {"name": "job", "spawned": True, "work": {"kind": "phases", "events": [{"run": "1ms"}]}},
                    {"name": "slow", "work": {"kind": "periodic", "period": "10ms"}},
                ],
            }
        ],
    }
    base.update(extra)
    return Scenario.parse(base)


def _planned(sc: Scenario) -> list[PlannedThread]:
    return plan_scenario(sc, Settings())


def test_a_worker_is_told_each_threads_settings_work_and_order_and_the_cpus_it_was_given() -> None:
    sc = _scenario(latency_bound="500us")
    threads = _planned(sc)
    layout = worker_layout(threads, 1_000_000_000, sc.samples)
    spec = process_spec(threads, sc, layout, {id(t): n for n, t in enumerate(threads)}, MACHINE)
    assert (spec["comm"], spec["all_cpus"], spec["capacity"]) == ("app", MACHINE, layout.capacity)
    assert spec["main"]["sched"] == [1, 80, None, None] and spec["main"]["work"][:3] == (_probe.WORK_PERIODIC, 1_000_000, 100_000)
    assert spec["main"]["work"][7] == 500_000, "the latency bound the native core marks outliers by"
    by_name = {t["name"]: t for t in spec["threads"]}
    assert (by_name["fast"]["sched"], by_name["fast"]["cpus"], by_name["fast"]["work"][1]) == ([1, 70, None, None], [1], 2_000_000)
    assert by_name["idle"]["work"][0] == _probe.WORK_SLEEP and by_name["idle"]["cpus"] is None
    assert by_name["job"]["spawned"] and by_name["job"]["work"][0] == _probe.WORK_PROGRAM
    # start: in_order: each after the one listed before it that starts with the cell; a spawned thread begins at its spawn
    assert [by_name[n]["after"] for n in ("fast", "idle", "job", "slow")] == [-1, 1, -1, 2]


def test_a_ring_holds_a_short_cell_whole_and_otherwise_what_the_runner_drains_in_time() -> None:
    threads = _planned(_scenario())
    second = 1_000_000_000
    assert ring_capacity(threads, second // 10, Samples()) == 100 + 16, "100 ms of the 1 ms main: the whole cell"
    assert ring_capacity(threads, 60 * second, Samples()) == 4096, "a minute: the floor, above two seconds of 1 ms"
    assert ring_capacity(threads, 60 * second, Samples.parse("last 300")) == 300, "last N: the ring is the N kept"
    assert ring_capacity(threads, 60 * second, Samples.parse("none")) == 0
    fastest = _planned(_scenario(processes=[{"name": "p", "threads": [{"name": "t", "work": {"kind": "periodic", "period": "10us"}}]}]))
    assert ring_capacity(fastest, 60 * second, Samples()) == RING_MAX, "two seconds of a 10 us period, capped"
    asleep = _planned(_scenario(processes=[{"name": "p", "threads": [{"name": "t"}]}]))
    assert ring_capacity(asleep, 60 * second, Samples()) == 0, "no callbacks, no ring"


def test_a_workers_buffer_has_room_for_its_longest_program_and_a_spawned_threads_first_settings() -> None:
    sc = _scenario()
    layout = worker_layout(_planned(sc), 1_000_000_000, sc.samples)
    assert layout.nthreads == 5
    assert (layout.events, layout.phases, layout.locks) == (2, 2, 0), "one event plus its chain; one phase plus the spawned start"


def test_hogs_are_processes_of_one_spinning_thread_or_one_process_of_spinning_threads_beside_a_sleeping_main() -> None:
    sc = _scenario(background={"hogs": [{"count": 2, "sched": "rr:5"}, {"count": 3, "kind": "thread", "name": "busy", "cpus": "0"}]})
    specs = hog_specs(sc, MACHINE)
    assert [(h.label, h.log_name, h.layout.nthreads) for h in specs] == [
        ("hog hog[0]", "hog0-0.log", 1),
        ("hog hog[1]", "hog0-1.log", 1),
        ("hog busy[0]", "hog1-0.log", 4),
    ]
    spin, sleep = work_tuple(SpinWork()), work_tuple(SleepWork())
    assert all(h.spec["all_cpus"] == MACHINE and h.layout.capacity == 0 for h in specs)
    assert (specs[0].spec["main"]["work"], specs[0].spec["main"]["sched"], specs[0].spec["threads"]) == (spin, [2, 5, None, None], [])
    assert (specs[2].spec["main"]["work"], specs[2].spec["main"]["cpus"]) == (sleep, [0])
    assert specs[2].spec["threads"] == [{"name": "busy", "work": spin}] * 3


def test_only_periodic_work_keeps_samples_and_a_program_brings_its_events() -> None:
    assert work_tuple(SpinWork())[8] == work_tuple(SleepWork())[8] == _probe.RING_NONE
    periodic = _planned(_scenario())[0].work
    assert work_tuple(periodic, samples=Samples.parse("outliers"))[8] == _probe.RING_OUTLIERS
    assert work_tuple(periodic, samples=Samples.parse("last 5"))[8] == _probe.RING_ALL, "the ring is the last N"
    assert work_tuple(periodic, samples=Samples.parse("none"))[8] == _probe.RING_NONE
    job = next(t.work for t in _planned(_scenario()) if isinstance(t.work, PhasesWork))
    program = wiring.program_tuple(job, 3, _scenario())
    assert program[0] == 3 and work_tuple(job, program=program)[-1] is program


def test_every_resource_kind_and_overrun_has_a_native_code() -> None:
    assert set(wiring._RESOURCE_KINDS) == set(ResourceKind)
    assert set(wiring._OVERRUN) == set(Overrun)
