"""Programs (`kind: phases`) without processes: the model, what the native core is told, and what its records mean."""

from __future__ import annotations

import dataclasses
import errno
import json
import mmap
import os
import struct
import subprocess
import sys
import time

import pytest

from runner import histogram as hg
from runner.run import _probe, kernel, programs, samples
from runner.run.evaluate import degradation
from runner.run.rawcell import ApplyErrors, RawThread
from runner.run.samples import EventStats, PhaseStats, SlotData, rows
from runner.run.wiring import lock_slots, program_sizes, program_tuple, resource_specs, start_after, work_tuple
from runner.scenario.model import Event, EventKind, PhasesWork, Policy, Scenario, Sched, Start
from runner.scenario.plan import CallbackKind, Settings, callback_kind, plan_scenario
from runner.scenario.typed import Invalid


def scenario(**extra) -> Scenario:
    base = {
        "name": "s",
        "resources": {"m": {"kind": "mutex", "protocol": "inherit"}, "tick": {"kind": "timer", "period": "5ms", "overrun": "rebase"}},
        "processes": [
            {
                "name": "app",
                "threads": [
                    {
                        "name": "a",
                        "work": {
                            "kind": "phases",
                            "loop": 3,
                            "phases": [
                                {"events": [{"timer": "tick"}, {"lock": "m"}, {"run": "1ms"}, {"unlock": "m"}, {"mem": "4KiB"}]},
                                {"name": "fast", "sched": "fifo:40", "cpus": "1", "loop": 2, "events": [{"timer": "tick"}, "yield"]},
                            ],
                        },
                    },
                    {"name": "b", "work": {"kind": "phases", "events": [{"timer": {"period": "5ms"}}, {"lock": "m"}, {"unlock": "m"}]}},
                ],
            }
        ],
    }
    base.update(extra)
    return Scenario.parse(base)


def test_events_read_in_their_short_forms_and_write_back_as_written():
    for written in (
        {"run": "200us"},
        "yield",
        {"wait": {"cond": "c", "mutex": "m"}},
        {"timer": {"period": "1ms", "overrun": "catchup"}},
        {"timer": "tick"},
        {"mem": "64KiB"},
        {"lock": "m"},
    ):
        assert Event.parse(written).dump() == written
    assert Event.parse({"broad": "c"}).event is EventKind.BROADCAST  # rt-app's name


@pytest.mark.parametrize(
    ("event", "words"),
    [
        ({"rn": "1ms"}, "unknown event 'rn'; did you mean 'run'?"),
        ({"run": "1ms", "lock": "m"}, "an event has exactly one key"),
        ({"timer": {}}, "names a timer of resources or has its own period"),
        ({"wait": "c"}, "wait needs its condition and mutex"),
        ({"yield": 3}, "yield takes no value"),
        ({"lock": None}, "lock needs a value"),
    ],
)
def test_a_malformed_event_says_what_to_write(event, words):
    with pytest.raises(Invalid, match=words.replace("?", r"\?").replace("(", r"\(")):
        Event.parse(event)


def test_locks_balance_within_a_phase_and_a_wait_holds_its_mutex():
    def work(events):
        return PhasesWork.parse({"events": events})

    work([{"lock": "m"}, {"wait": {"cond": "c", "mutex": "m"}}, {"unlock": "m"}])
    for events, words in (
        ([{"unlock": "m"}], "unlock m without a lock m"),
        ([{"lock": "m"}, {"lock": "m"}], "already holds it would deadlock"),
        ([{"lock": "m"}], "the phase ends holding m"),
        ([{"wait": {"cond": "c", "mutex": "m"}}], "needs its mutex m held"),
    ):
        with pytest.raises(Invalid, match=words):
            work(events)


def test_deadline_defaults_follow_rt_app_and_the_kernels_order_is_checked():
    only = Sched.parse({"policy": "deadline", "runtime": "2ms"})
    assert (only.runtime, only.deadline, only.period) == (2_000_000, 2_000_000, 2_000_000)
    short = Sched.parse("deadline:2ms/8ms/10ms")
    assert (short.runtime, short.deadline, short.period, short.label()) == (2_000_000, 8_000_000, 10_000_000, "deadline 2ms/8ms/10ms")
    assert Sched.parse("deadline:2ms/8ms").period == 8_000_000
    assert short.bandwidth == pytest.approx(0.2)
    for bad, words in (
        ("deadline", "needs a runtime"),
        ("deadline:1us", "below the kernel's minimum"),
        ("deadline:5ms/4ms/10ms", "runtime <= deadline"),
    ):
        with pytest.raises(Invalid, match=words):
            Sched.parse(bad)
    with pytest.raises(Invalid, match="runtime, deadline and period are for policy deadline"):
        Sched.parse({"policy": "fifo", "priority": 5, "runtime": "1ms"})
    assert Sched.parse("fifo:80").dump() == {"policy": "fifo", "priority": 80, "nice": None}


def test_the_native_core_gets_resources_by_index_and_each_phases_settings():
    sc = scenario()
    assert resource_specs(sc) == [(_probe.RES_MUTEX, 1, 0, 0), (_probe.RES_TIMER, 0, 0, 5_000_000)]
    a = sc.processes[0].threads[0].work
    assert isinstance(a, PhasesWork)
    gid, delay, loop, mem, phases, events = program_tuple(a, 7, sc)
    assert (gid, delay, loop, mem) == (7, 0, 3, 4096)
    assert events[0] == (_probe.EV_TIMER, 1, -1, _probe.OVR_REBASE, 5_000_000)  # the named timer's period and overrun
    assert events[1] == (_probe.EV_LOCK, 0, 0, _probe.OVR_SKIP, 0) and events[2][4] == 1_000_000  # m: the thread's lock slot 0
    assert phases[0] == (1, 0, 5, None)
    assert phases[1] == (2, 5, 2, (1, 40, None, [1], None))


def test_each_mutex_a_thread_locks_has_a_lock_slot_in_the_order_it_is_first_locked_up_to_eight():
    names = [f"m{i}" for i in range(10)]
    events = [{"timer": {"period": "10ms"}}]
    for name in ["m3", *names]:  # m3 first, then every one, m3 again among them
        events += [{"lock": name}, {"unlock": name}]
    sc = Scenario.parse(
        {
            "name": "slots",
            "resources": {name: {"kind": "mutex"} for name in names},
            "processes": [{"name": "app", "threads": [{"name": "t", "work": {"kind": "phases", "events": events}}]}],
        }
    )
    work = sc.processes[0].threads[0].work
    assert isinstance(work, PhasesWork)
    assert work.locked_mutexes() == ("m3", "m0", "m1", "m2", "m4", "m5", "m6", "m7", "m8", "m9")
    assert lock_slots(work) == ("m3", "m0", "m1", "m2", "m4", "m5", "m6", "m7")
    *_, native = program_tuple(work, 0, sc)
    slot_of_lock = [(sc_names[e[1]], e[2]) for e in native if e[0] == _probe.EV_LOCK for sc_names in [list(sc.resources)]]
    assert slot_of_lock[:2] == [("m3", 0), ("m0", 1)] and ("m3", 0) in slot_of_lock[2:]
    assert ("m8", -1) in slot_of_lock and ("m9", -1) in slot_of_lock, "beyond eight: in the activation's total only"


def test_a_program_with_a_timer_has_callbacks_at_its_period():
    threads = plan_scenario(scenario(), Settings())
    assert [(t.name, t.period, t.periodic) for t in threads] == [
        ("app", None, False),
        ("a", 5_000_000, True),
        ("b", 5_000_000, True),
    ]


def test_a_thread_whose_phases_follow_timers_of_other_periods_has_each_of_them_shortest_first():
    s = Scenario.parse(
        {
            "name": "periods",
            "resources": {"slow": {"kind": "timer", "period": "50ms"}},
            "processes": [
                {
                    "name": "app",
                    "main": {
                        "work": {
                            "kind": "phases",
                            "phases": [
                                {"events": [{"timer": {"period": "20ms"}}, {"run": "1ms"}]},
                                {"events": [{"timer": "slow"}, {"run": "2ms"}]},
                                {"events": [{"timer": {"period": "10ms"}}, {"run": "1ms"}]},
                            ],
                        }
                    },
                }
            ],
        }
    )
    (main,) = plan_scenario(s, Settings())
    assert (main.periods, main.period) == ((10_000_000, 20_000_000, 50_000_000), 10_000_000)


def test_a_stage_without_a_timer_that_suspends_is_released_by_resumes():
    queued = scenario(
        resources={"hop": {"kind": "queue"}, "tick": {"kind": "timer", "period": "5ms"}},
        processes=[
            {
                "name": "app",
                "threads": [
                    {"name": "first", "work": {"kind": "phases", "events": [{"timer": "tick"}, {"resume": "hop"}]}},
                    {"name": "stage", "work": {"kind": "phases", "events": [{"suspend": "hop"}, {"run": "1ms"}]}},
                    {"name": "both", "work": {"kind": "phases", "events": [{"timer": "tick"}, {"suspend": "hop"}, {"resume": "hop"}]}},
                    {"name": "idle", "work": {"kind": "phases", "events": [{"sleep": "1ms"}]}},
                ],
            }
        ],
    )
    threads = plan_scenario(queued, Settings())
    assert [(t.name, t.period, t.released, t.has_callbacks) for t in threads] == [
        ("app", None, False, False),
        ("first", 5_000_000, False, True),
        ("stage", None, True, True),
        ("both", 5_000_000, False, True),  # a timer releases its activations; the suspend is a step of one
        ("idle", None, False, False),
    ]
    kinds = [CallbackKind.NONE, CallbackKind.PERIODIC, CallbackKind.RESUMED, CallbackKind.PERIODIC, CallbackKind.NONE]
    assert [t.callbacks for t in threads] == [callback_kind(t.work) for t in threads] == kinds


def stats(values: list[int], holders=()) -> EventStats:
    h = hg.from_values(values)
    mean = sum(values) / len(values) if values else 0.0
    return EventStats(
        count=len(values),
        total=sum(values),
        mean=mean,
        m2=sum((v - mean) ** 2 for v in values),
        histogram=h,
        holders=tuple(holders),
        contended=len(holders),
    )


def test_event_records_are_named_and_locks_merge_into_the_threads_lock_wait():
    sc = scenario()
    a = sc.processes[0].threads[0].work
    assert isinstance(a, PhasesWork)
    events = [
        stats([100]),
        stats([1_000, 3_000], [(1, 2, 4_000)]),
        stats([1_000_000]),
        stats([50]),
        stats([10]),
        stats([20]),
        stats([5]),
        stats([]),
    ]
    phase = PhaseStats(passes=3, time_ns=9, entered=3, policy=0, read_back=True, affinity=(0, 1), cpus_seen=(0,))
    fast = PhaseStats(passes=6, entered=3, policy=1, priority=40, read_back=True, affinity=(1,), cpus_seen=(1,), errors=(0, 0, 0))
    slot = SlotData(1, "done", 0, 0, 0, 0, 0, (0,) * 4, (0,) * 4, 0, 0, 0, 0, (), events=tuple(events), phases=(phase, fast))
    results, phases, figures = programs.program_results(a, slot, Settings(), {1: "app/b #2"}, (0, 1))
    lock = results[1]
    assert (lock.event, lock.measures, lock.count, lock.contended) == ("lock m", "wait", 2, 1)
    assert [(h.thread, h.contentions, h.wait_ns) for h in lock.holders] == [("app/b #2", 2, 4_000)]
    assert results[0].measures == "latency" and results[2].measures == "wall"
    assert figures["lock_wait_ns"] is not None and figures["lock_wait_ns"].max == 3_000 and figures["lock_wait_ns"].mean == 2_000
    assert figures["chain_ns"] is None
    assert [p.name for p in phases] == ["p0", "fast"]
    assert phases[0].applied == Settings() and phases[0].requested is None
    assert phases[1].applied == Settings(Policy.FIFO, 40, 0, (1,)) and phases[1].degraded == []


def test_a_phase_the_kernel_refused_says_so_with_its_reason():
    sc = scenario()
    a = sc.processes[0].threads[0].work
    assert isinstance(a, PhasesWork)
    refused = PhaseStats(passes=6, entered=3, policy=0, read_back=True, affinity=(1,), errors=(errno.EPERM, 0, 0))
    slot = SlotData(1, "done", 0, 0, 0, 0, 0, (0,) * 4, (0,) * 4, 0, 0, 0, 0, (), phases=(PhaseStats(), refused))
    _, phases, _ = programs.program_results(a, slot, Settings(), {}, (0, 1))
    assert phases[1].degraded == ["policy fifo:40 requested, other applied (Operation not permitted)"]


def _cell_of(threads: dict[str, list[object]], resources: dict[str, str]) -> list[RawThread]:
    """Raw threads of one process `app` whose threads run the given events (in that order: gid = position)."""
    spec = Scenario.parse(
        {
            "name": "s",
            "resources": {name: {"kind": kind} for name, kind in resources.items()},
            "processes": [{"name": "app", "threads": [{"name": n, "work": {"kind": "phases", "events": e}} for n, e in threads.items()]}],
        }
    )
    planned = [t for t in plan_scenario(spec, Settings()) if t.index > 0]
    return [
        RawThread(p, 1, SlotData(10 + i, "done", *(0,) * 5, (0,) * 4, (0,) * 4, 0, 0, 0, 0, ()), None, ApplyErrors(), True)
        for i, p in enumerate(planned)
    ]


def _at(t: RawThread, **slot: int) -> RawThread:
    return dataclasses.replace(t, slot=dataclasses.replace(t.slot, **slot))


END = 2_000_000_000


def test_threads_blocked_at_the_end_that_nothing_going_could_release_are_stuck():
    """A deadlock that began at 1.2 s of 2 s once ended `passed`; the rule was half the run blocked."""
    ab = [{"lock": "a"}, {"run": "1ms"}, {"lock": "b"}, {"unlock": "b"}, {"unlock": "a"}]
    ba = [{"lock": "b"}, {"run": "1ms"}, {"lock": "a"}, {"unlock": "a"}, {"unlock": "b"}]
    first, second = _cell_of({"first": ab, "second": ba}, {"a": "mutex", "b": "mutex"})
    threads = [
        _at(first, blocked_since_ns=1_220_000_000, cur_event=2, cur_phase=0),
        _at(second, blocked_since_ns=1_221_000_000, cur_event=2, cur_phase=0),
    ]
    out = programs.stalls(threads, END, {0: "app/first", 1: "app/second"})
    assert out == [
        "app/first was blocked in `lock b` (phase p0, event 2) for the last 780.00 ms of the run; its holder, app/second, was stuck too",
        "app/second was blocked in `lock a` (phase p0, event 2) for the last 779.00 ms of the run; its holder, app/first, was stuck too",
    ]
    assert programs.stalls(threads[:1], END, {}) == [], "nobody holds b: the waiter is about to take it"


def test_a_stage_whose_producer_goes_on_is_waiting_however_long_and_one_whose_producer_finished_is_stuck():
    """A filter behind a sensor that slowed to a 2 s heartbeat once erred: it had waited 12 ms before, 700 ms at the end."""
    sensor, sink = _cell_of(
        {"sensor": [{"timer": {"period": "2s"}}, {"resume": "q"}], "filter": [{"suspend": "q"}, {"run": "1ms"}]}, {"q": "queue"}
    )
    waiting = _at(sink, blocked_since_ns=1_300_000_000, cur_event=0, cur_phase=0)
    assert programs.stalls([sensor, waiting], END, {}) == []
    finished = _at(sensor, work_end_ns=1_200_000_000)
    assert programs.stalls([finished, waiting], END, {1: "app/filter"}) == [
        "app/filter was blocked in `suspend q` (phase p0, event 0) for the last 700.00 ms of the run; "
        "no thread that resumes q was still going"
    ]
    brief = _at(sink, blocked_since_ns=END - 50_000_000, cur_event=0, cur_phase=0)
    assert programs.stalls([finished, brief], END, {}) == [], "blocked 50 ms: the end came, not a deadlock"


def test_a_deadline_refusal_is_explained_with_the_cells_bandwidth_and_the_kernels_limit():
    sc = Scenario.parse(
        {
            "name": "d",
            "processes": [{"name": "p", "instances": 2, "threads": [{"name": "g", "count": 2, "sched": "deadline:6ms/10ms/10ms"}]}],
        }
    )
    words = programs.deadline_admission(sc, 950_000, 1_000_000, 2)
    assert "this cell asks 2.40 CPUs of bandwidth (g 0.60, g 0.60, g 0.60, g 0.60)" in words
    assert "at most 0.95 per CPU x 2 CPUs = 1.90 (sched_rt_runtime_us 950000 / sched_rt_period_us 1000000)" in words
    requested = Settings(Policy.DEADLINE, 0, 0, None, 6_000_000, 10_000_000, 10_000_000)
    out = degradation(requested, Settings(), ApplyErrors(sched=errno.EBUSY), words)
    assert out == [f"policy deadline 6ms/10ms/10ms requested, other applied ({words})"]


def test_histograms_merge_exactly_to_the_bucket():
    a, b = hg.from_values([1, 300, 5_000]), hg.from_values([300, 9_000_000])
    merged = hg.merge([a, None, b])
    assert merged == hg.from_values([1, 300, 5_000, 300, 9_000_000])
    assert hg.merge([None]) is None


def spawning(**template) -> Scenario:
    """A dispatcher (FIFO 30, then FIFO 50 in its second phase) spawning `job` there; `template` overrides job's spec."""
    job = {"name": "job", "spawned": True, "count": 3, "work": {"kind": "phases", "loop": 1, "events": [{"run": "1ms"}, {"iorun": "4MiB"}]}}
    return Scenario.parse(
        {
            "name": "s",
            "processes": [
                {
                    "name": "app",
                    "threads": [
                        {
                            "name": "boss",
                            "sched": "fifo:30",
                            "work": {
                                "kind": "phases",
                                "phases": [
                                    {"events": [{"sleep": "1ms"}]},
                                    {"sched": "fifo:50", "cpus": "1", "events": [{"timer": {"period": "10ms"}}, {"spawn": "job"}]},
                                ],
                            },
                        },
                        {**job, **template},
                    ],
                }
            ],
        }
    )


def test_a_spawned_thread_is_planned_with_its_spawners_settings_at_the_spawn():
    planned = {t.name: t for t in plan_scenario(spawning(), Settings())}
    assert [planned[f"job-{i}"].spawned for i in range(3)] == [True] * 3 and not planned["boss"].spawned
    assert (planned["job-0"].settings.policy, planned["job-0"].settings.priority, planned["job-0"].settings.cpus) == (Policy.FIFO, 50, (1,))
    explicit = {t.name: t for t in plan_scenario(spawning(inherit=False, sched="rr:5"), Settings())}
    assert (explicit["job-2"].settings.policy, explicit["job-2"].settings.priority, explicit["job-2"].settings.cpus) == (Policy.RR, 5, None)


def test_the_native_core_gets_a_spawn_as_the_templates_first_slot_and_count_and_iorun_a_buffer():
    sc = spawning()
    _, _, _, mem, _, events = program_tuple(sc.processes[0].threads[0].work, 1, sc, {"job": (2, 3)})
    assert events[-1] == (_probe.EV_SPAWN, 2, -1, _probe.OVR_SKIP, 3)
    _, _, _, mem, _, events = program_tuple(sc.processes[0].threads[1].work, 2, sc)
    assert events[-1] == (_probe.EV_IORUN, -1, -1, _probe.OVR_SKIP, 4 << 20) and mem == 1 << 20  # written in 1 MiB chunks


def test_spawn_events_read_and_write_back_as_written():
    ev = Event.parse({"spawn": "job"})
    assert (ev.event, ev.thread, ev.dump(), ev.label()) == (EventKind.SPAWN, "job", {"spawn": "job"}, "spawn job")
    with pytest.raises(Invalid, match="thread belongs to spawn events"):
        Event.parse({"event": "run", "duration": "1ms", "thread": "job"})


def test_dropped_spawns_and_instances_never_spawned_are_warnings_in_words():
    from reportdata import main_thread, matrix

    from runner.results.document import EventResult
    from runner.run.evaluate import spawn_warnings

    boss = main_thread(matrix().cells[0]).model_copy(
        update={"events": [EventResult(phase="p0", index=0, event="spawn job", kind="spawn", measures="wall", count=3, dropped=4)]}
    )
    out = spawn_warnings([boss], ["app/job"], 1)
    assert out == [
        f"{boss.label(False)}: 4 `spawn job` found every instance taken (or the kernel refused the thread);"
        " raise the spawned thread's count",
        "app/job: never spawned: no spawn event naming it ran",
    ]


def test_uclamp_is_refused_before_the_run_on_a_kernel_without_it(monkeypatch, tmp_path):
    from runner.run import preflight

    def with_phase(sched: object) -> Scenario:
        phase = {"events": [{"run": "1ms"}], **({"sched": sched} if sched else {})}
        hint = {"name": "hint", "work": {"kind": "phases", "phases": [phase]}}
        return Scenario.parse({"name": "s", "processes": [{"name": "app", "threads": [{"name": "plain", "sched": "fifo:10"}, hint]}]})

    sc, clamped = with_phase(None), with_phase({"policy": "other", "util_max": 512})
    perm = preflight.current_permissions()
    assert preflight.needs([sc], Settings(), False, {0, 1}).uclamp is None
    wanted = preflight.needs([clamped], Settings(), False, {0, 1})
    assert wanted.uclamp == "app/hint phase p0"
    monkeypatch.setattr(preflight, "UCLAMP_KNOB", str(tmp_path / "absent"))
    assert any(
        m.startswith("app/hint phase p0 asks for util_min / util_max (uclamp), which this kernel does not have")
        for m in preflight.missing_rights(perm, wanted)
    )
    (tmp_path / "knob").write_text("1024\n")
    monkeypatch.setattr(preflight, "UCLAMP_KNOB", str(tmp_path / "knob"))
    assert not any("uclamp" in m for m in preflight.missing_rights(perm, wanted))


@pytest.mark.skipif(os.path.exists("/proc/sys/kernel/sched_util_clamp_min"), reason="this kernel has uclamp")
def test_a_scenario_asking_uclamp_of_a_kernel_without_it_exits_3_and_starts_nothing(tmp_path):
    from conftest import run_cli

    path = tmp_path / "u.yaml"
    path.write_text(
        "name: u\nprocesses:\n  - name: uclamped\n    threads:\n      - name: t\n        sched: {policy: other, util_min: 100}\n"
    )
    out = run_cli(str(path), "--out", str(tmp_path / "out"), "--duration", "0.1s")
    assert out.code == 3, out.err
    assert "uclamped/t asks for util_min / util_max (uclamp), which this kernel does not have" in out.err
    assert not (tmp_path / "out").exists()


def test_drops_of_one_spawn_event_by_many_threads_are_one_warning():
    from reportdata import main_thread, matrix

    from runner.results.document import EventResult
    from runner.run.evaluate import spawn_warnings

    base = main_thread(matrix().cells[0])
    spawn = EventResult(phase="p0", index=0, event="spawn c", kind="spawn", measures="wall", count=1, dropped=5)
    copies = [base.model_copy(update={"index": i, "events": [spawn]}) for i in range(3)]
    assert spawn_warnings(copies, [], 1) == [
        f"{base.process} (3 threads): 15 `spawn c` found every instance taken (or the kernel refused the thread);"
        " raise the spawned thread's count"
    ]


def test_the_native_core_writes_what_the_reader_reads_with_lock_slots_after_each_sample(tmp_path):
    """A worker's three threads in this process (no rights needed): a periodic one, whose samples carry empty
    lock slots, and a program that locks n then m every 2 ms; the buffer's own header, and every sample
    the reader takes back, agree with the Python layout (its stride moves the last slot past the others)."""
    sc = Scenario.parse(
        {
            "name": "slots",
            "resources": {"m": {"kind": "mutex"}, "n": {"kind": "mutex"}},
            "processes": [
                {
                    "name": "app",
                    "threads": [
                        {"name": "tick", "work": {"kind": "periodic", "period": "2ms"}},
                        {
                            "name": "locker",
                            "work": {
                                "kind": "phases",
                                "events": [{"timer": {"period": "2ms"}}, {"lock": "n"}, {"unlock": "n"}, {"lock": "m"}, {"unlock": "m"}],
                            },
                        },
                    ],
                }
            ],
        }
    )
    planned = plan_scenario(sc, Settings())
    events, phases = program_sizes(planned)
    layout = samples.Layout(3, 64, events=events, phases=phases, locks=max(len(lock_slots(t.work)) for t in planned))
    assert layout.locks == 2
    fd = samples.create("slots", layout)
    res = mmap.mmap(-1, len(sc.resources) * _probe.RES_BYTES)
    _probe.init_resources(res, resource_specs(sc))
    try:
        group = _probe.Group(mmap.mmap(fd, layout.size), 3, 64, kernel.online_cpus(), True, events, phases, res, layout.locks)
        works = [
            work_tuple(t.work, program=program_tuple(t.work, t.index, sc) if isinstance(t.work, PhasesWork) else None) for t in planned
        ]
        group.adopt(0, "slots-main", works[0])
        for t in planned[1:]:
            group.spawn(t.index, t.name, works[t.index], None, None, None, None, False, None, False)
        assert group.wait_ready(5.0)
        now = time.monotonic_ns()
        group.release(now + 5_000_000, now + 45_000_000)
        group.run_main(0)
        group.join()
        reader = samples.Buffer(fd, layout)
        header = struct.unpack_from("<8s6IQ", reader.map, 0)
        assert (header[0], header[5], header[7]) == (b"RSMP0007", layout.sample_size, layout.stride)
        tick, locker = reader.drain(1, stopped=True), reader.drain(2, stopped=True)
    finally:
        _probe.set_name("pytest")
        os.close(fd)
    assert len(tick) >= 10 and all(s.period_ns == 2_000_000 and s.next_ns == s.scheduled_ns + 2_000_000 for s in tick)
    assert all(all(w.taken == 0 for w in s.locks) for s in tick), "a periodic thread locks nothing"
    assert len(locker) >= 10 and [s.seq for s in locker] == list(range(len(locker)))
    for s in locker:
        (n, m) = s.locks  # slots in the order the program first locks them
        assert (n.taken, n.contended, n.holder, m.taken, m.contended, m.holder) == (1, 0, -1, 1, 0, -1)
        assert n.wait_ns + m.wait_ns == s.lock_wait_ns
        assert s.period_ns == 2_000_000 and s.next_ns == s.scheduled_ns + 2_000_000
    written = rows("app[0]/locker #2", 1, locker, lock_slots(planned[2].work))
    assert set(json.loads(str(written[0][-1]))) == {"n", "m"}


_BURN_STOPPED = """
import mmap, os, signal, sys, threading, time
from runner.run import _probe, kernel, samples
from runner.run.wiring import work_tuple
from runner.scenario.model import PeriodicWork

_probe.install_stop_handler()
layout = samples.Layout(1, 16)
fd = samples.create("burn-stop", layout)
group = _probe.Group(mmap.mmap(fd, layout.size), 1, 16, kernel.online_cpus(), False, 0, 0, None, 0)
work = work_tuple(PeriodicWork.parse({"period": "2s", "burn": "1.5s", "burn_clock": "wall"}))
group.spawn(0, "burner", work, None, None, None, None, False, None, False)
assert group.wait_ready(5.0)
now = time.monotonic_ns()
group.release(now + 1_000_000, now + int(sys.argv[1]))
threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGUSR1)).start()
group.join()
print((time.monotonic_ns() - now) // 1_000_000)
"""


@pytest.mark.parametrize("end_ms", [250, 5_000])
def test_a_callbacks_burn_ends_at_a_stop_whenever_the_run_ends(end_ms: int, tmp_path) -> None:
    """A periodic callback of a 2 s period burning 1.5 s of wall time, stopped 0.2 s in (SIGUSR1, as the runner stops
    a worker), ends there: its burn checked no stop, so a callback of an hour's period at an RT priority spun on
    through the runner's stop, before the run's end (5 s) or after it (0.25 s: a callback under way at the end
    runs to its own end, measured, unless stopped)."""
    done = subprocess.run(  # not in the clone: `-c` would import its source tree, whose extension CI does not build
        [sys.executable, "-c", _BURN_STOPPED, str(end_ms * 1_000_000)], capture_output=True, text=True, timeout=30, cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr
    assert int(done.stdout) < 1_000, f"joined {done.stdout.strip()} ms after the release, the stop came at 200 ms"


def test_the_report_says_the_policy_a_programs_callbacks_ran_at_as_its_phases_read_it_back():
    """Issue 40: a thread whose one phase ran at FIFO 99 read `at OTHER` (its settings as it started, not the phase's)."""
    from reportdata import main_thread, matrix

    from runner.report.cellview import render_cell
    from runner.report.markdown import thread_finding
    from runner.results.document import EventResult, PhaseResult

    cell = matrix().cells[0]
    base = main_thread(cell).model_copy(update={"applied": Settings()})
    timer = EventResult(phase="urgent", index=1, event="timer 10ms", kind="timer", measures="latency", count=99)
    setup = PhaseResult(name="setup", passes=1, entered=1, applied=Settings())
    urgent = PhaseResult(name="urgent", passes=99, entered=1, applied=Settings(Policy.FIFO, 99))
    one = base.model_copy(update={"events": [timer], "phases": [setup, urgent]})
    assert one.callback_settings() == [Settings(Policy.FIFO, 99)], "its callbacks ran in the phase with the timer"
    assert "**phased/mover** at FIFO 99:" in thread_finding(one, "phased/mover")
    both = one.model_copy(update={"events": [timer, timer.model_copy(update={"phase": "setup"})]})
    assert "**phased/mover** at OTHER, then FIFO 99:" in thread_finding(both, "phased/mover")
    assert thread_finding(base, "x").startswith("**x** at OTHER:"), "a thread without phases: as read back at its start"
    cell = cell.model_copy(update={"threads": [one]})
    assert "fifo:99" in render_cell(cell) and " other " not in render_cell(cell).split("applied", 1)[1]


def test_a_queue_says_what_becomes_of_a_resume_nobody_waits_for_and_only_a_queue_says_it():
    """pending: keep (the default, left out of the spec) or drop (rt-app's resume, issue 40, 13), as the native core's protocol."""
    sc = scenario(
        resources={
            "q": {"kind": "queue", "pending": "drop"},
            "k": {"kind": "queue"},
            "m": {"kind": "mutex"},
            "tick": {"kind": "timer", "period": "5ms"},
        }
    )
    assert resource_specs(sc)[:2] == [(_probe.RES_QUEUE, _probe.QUEUE_DROP, 0, 0), (_probe.RES_QUEUE, _probe.QUEUE_KEEP, 0, 0)]
    assert sc.resources["q"].dump()["pending"] == "drop"
    assert "pending" not in sc.resources["k"].dump()  # a spec hash of before it existed
    with pytest.raises(Invalid, match="pending is for queues, not a mutex"):
        scenario(resources={"m": {"kind": "mutex", "pending": "drop"}, "tick": {"kind": "timer", "period": "5ms"}})


def test_threads_that_start_in_order_each_begin_after_the_one_listed_before_that_starts_with_the_cell():
    """start: in_order (issue 40, 14): each thread's slot begins after the previous one's; spawned ones are at no start."""
    assert start_after([False, False, True, False]) == {2: 1, 4: 2}
    assert start_after([True, False]) == {}
    base = scenario().processes[0]
    assert base.start is Start.TOGETHER and "start" not in base.dump()
    ordered = scenario(processes=[{**base.dump(), "start": "in_order"}]).processes[0]
    assert ordered.start is Start.IN_ORDER and ordered.dump()["start"] == "in_order"


def _native_run(sc: Scenario, run_ms: int, after: dict[int, int] | None = None) -> tuple[list[SlotData], mmap.mmap]:
    """Run a scenario's one process in this process (no rights needed): its slots as the reader takes them, and its resources."""
    planned = plan_scenario(sc, Settings())
    events, phases = program_sizes(planned)
    layout = samples.Layout(len(planned), 64, events=events, phases=phases, locks=max(len(lock_slots(t.work)) for t in planned))
    fd = samples.create("native", layout)
    res = mmap.mmap(-1, max(1, len(sc.resources)) * _probe.RES_BYTES)
    _probe.init_resources(res, resource_specs(sc))
    try:
        group = _probe.Group(mmap.mmap(fd, layout.size), len(planned), 64, kernel.online_cpus(), True, events, phases, res, layout.locks)
        works = [
            work_tuple(t.work, program=program_tuple(t.work, t.index, sc) if isinstance(t.work, PhasesWork) else None) for t in planned
        ]
        group.adopt(0, "native-main", works[0])
        for t in planned[1:]:
            begins = (after[t.index],) if after and t.index in after else ()  # (not passed without one: an older core takes none)
            group.spawn(t.index, t.name, works[t.index], None, None, None, None, False, None, False, *begins)
        assert group.wait_ready(5.0)
        now = time.monotonic_ns()
        group.release(now + 5_000_000, now + 5_000_000 + run_ms * 1_000_000)
        group.run_main(0)
        group.join()
        return samples.Buffer(fd, layout).slots(), res
    finally:
        _probe.set_name("pytest")
        os.close(fd)


def _one_process(*threads: dict, resources: dict | None = None) -> Scenario:
    return Scenario.parse({"name": "n", "resources": resources or {}, "processes": [{"name": "app", "threads": list(threads)}]})


def test_a_resume_of_a_queue_that_drops_is_lost_when_nobody_waits_and_counted_on_its_event():
    """The first resume comes before anyone suspends: lost (rt-app's broadcast of nobody), the second wakes the waiter."""
    sc = _one_process(
        {"name": "p", "work": {"kind": "phases", "loop": 1, "events": [{"resume": "q"}, {"sleep": "20ms"}, {"resume": "q"}]}},
        {"name": "c", "work": {"kind": "phases", "loop": 1, "events": [{"sleep": "5ms"}, {"suspend": "q"}]}},
        resources={"q": {"kind": "queue", "pending": "drop"}},
    )
    slots, res = _native_run(sc, 200)
    producer, consumer = slots[1], slots[2]
    assert [e.count for e in producer.events[:3]] == [1, 1, 1] and [e.dropped for e in producer.events[:3]] == [1, 0, 0]
    assert consumer.events[1].count == 1 and consumer.events[1].cut == 0  # woken by the second
    results, _, _ = programs.program_results(sc.processes[0].threads[0].work, producer, Settings(), {}, (0,))
    assert (results[0].lost, results[0].dropped, results[2].lost) == (1, 0, 0)
    assert struct.unpack_from("<iiiiq6q", res, 0)[8] == 1  # the queue's own count of what it lost


def test_an_event_the_end_of_the_run_cuts_short_is_counted_as_cut_not_as_a_finished_event():
    """A 200 ms sleep, a 300 ms run and a suspend nobody resumes under way at the end of a 100 ms run (issue 40, 15): each
    counted as cut, none recorded with the time it got (a sleep of 200 ms once showed as 76 ms)."""
    sc = _one_process(
        {"name": "s", "work": {"kind": "phases", "loop": 1, "events": [{"sleep": "10ms"}, {"sleep": "200ms"}]}},
        {"name": "r", "work": {"kind": "phases", "loop": 1, "events": [{"run": "300ms"}]}},
        {"name": "w", "work": {"kind": "phases", "loop": 1, "events": [{"suspend": "q"}]}},
        {"name": "x", "work": {"kind": "phases", "loop": 1, "events": [{"sleep": "500ms"}, {"resume": "q"}]}},
        resources={"q": {"kind": "queue"}},
    )
    slots, _ = _native_run(sc, 100)
    sleeper, runner_, waiter = slots[1], slots[2], slots[3]
    assert [(e.count, e.cut) for e in sleeper.events[:2]] == [(1, 0), (0, 1)]
    assert (runner_.events[0].count, runner_.events[0].cut) == (0, 1)
    assert (waiter.events[0].count, waiter.events[0].cut) == (0, 1)
    results, _, _ = programs.program_results(sc.processes[0].threads[0].work, sleeper, Settings(), {}, (0,))
    assert (results[1].count, results[1].cut, results[1].spread_ns) == (0, 1, None)


def test_a_slot_that_begins_after_another_begins_once_that_one_has():
    """The native start order: slot 3 after slot 2 after slot 1, whatever the scheduler would have run first."""
    sc = _one_process(*({"name": f"t{i}", "work": {"kind": "phases", "loop": 1, "events": [{"run": "2ms"}]}} for i in range(3)))
    slots, _ = _native_run(sc, 100, after={2: 1, 3: 2})
    began = [s.work_start_ns for s in slots[1:]]
    assert all(began) and began == sorted(began), began
    with pytest.raises(ValueError, match="cannot begin after slot 2"):
        planned = plan_scenario(sc, Settings())
        layout = samples.Layout(len(planned), 16, events=2, phases=1)
        fd = samples.create("bad", layout)
        try:
            group = _probe.Group(mmap.mmap(fd, layout.size), len(planned), 16, kernel.online_cpus(), True, 2, 1, None, 0)
            group.spawn(
                1,
                "t0",
                work_tuple(planned[1].work, program=program_tuple(planned[1].work, 1, sc)),
                None,
                None,
                None,
                None,
                False,
                None,
                False,
                2,
            )
        finally:
            os.close(fd)


def _issues(data: dict) -> dict[str, str]:
    """Every issue of a scenario that does not parse, by its dotted key path."""
    from runner.scenario.yamlsource import dotted

    with pytest.raises(Invalid) as caught:
        Scenario.parse(data)
    return {dotted(i.path): i.message for i in caught.value.issues}


def test_words_of_rt_app_and_cyclictest_are_answered_with_what_they_are_here():
    """instance once answered "did you mean 'distance'?", fork named no spawn, a thread's loop and phases did not point at
    its work, and an unknown key of a timer listed the event's inner fields under the event's path (issue 40, 16)."""
    thread = {
        "name": "t",
        "instance": 2,
        "loop": 3,
        "phases": [],
        "priority": 80,
        "work": {"kind": "phases", "events": [{"fork": "job"}, {"timer": {"period": "1ms", "mode": "absolute"}}]},
    }
    said = _issues({"name": "s", "tasks": {}, "processes": [{"name": "app", "threads": [thread]}]})
    at = "processes[0].threads[0]"
    assert said[f"{at}.instance"] == "unknown key 'instance'; rt-app's instance is count here (count: 4 makes name-0 .. name-3)"
    assert said[f"{at}.loop"].startswith("unknown key 'loop'; a thread's loop belongs to its program: work: {kind: phases, loop: 3")
    assert said[f"{at}.phases"].startswith("unknown key 'phases'; phases belong to the thread's program: work: {kind: phases, phases:")
    assert said[f"{at}.priority"].startswith("unknown key 'priority'; the priority is part of sched: sched: fifo:80 (cyclictest -p80)")
    assert said["tasks"].startswith("unknown key 'tasks'; rt-app's tasks are the threads of a process here")
    assert said[f"{at}.work.phases[0].events[0]"].startswith("unknown event 'fork'; rt-app's fork is spawn here: {spawn: job}")
    assert said[f"{at}.work.phases[0].events[1].timer.mode"] == (
        "unknown key 'mode'; rt-app's timer mode is overrun here: relative is overrun: rebase, absolute is overrun: catchup"
    )
    assert not any("distance" in m or "expected one of: event, duration" in m for m in said.values()), said


def test_an_unknown_key_of_a_timer_or_a_wait_is_said_at_its_place_among_that_mappings_own_keys():
    events = [
        {"timer": {"period": "1ms", "overun": "skip"}},
        {"timer": {"period": "1ms", "phase": 1}},
        {"wait": {"ref": "c", "mutex": "m"}},
    ]
    thread = {"name": "t", "work": {"kind": "phases", "events": events}}
    said = _issues({"name": "s", "processes": [{"name": "app", "threads": [thread]}]})
    at = "processes[0].threads[0].work.phases[0].events"  # (the model's path: events: is its one phase)
    assert said[f"{at}[0].timer.overun"] == "unknown key 'overun'; did you mean 'overrun'?"
    assert said[f"{at}[1].timer.phase"] == "unknown key 'phase'; expected one of: period, overrun"
    assert said[f"{at}[2].wait.ref"] == "unknown key 'ref'; rt-app's ref is cond here: {wait: {cond: c, mutex: m}}"
    periodic = {"name": "t", "work": {"kind": "periodic", "interval": "1ms"}}
    said = _issues({"name": "s", "processes": [{"name": "app", "threads": [periodic]}]})
    assert said == {
        "processes[0].threads[0].work.interval": "unknown key 'interval'; cyclictest's interval is period here (-i1000: period: 1ms)"
    }
