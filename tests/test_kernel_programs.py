"""Programs (`kind: phases`) against the real kernel: the shipped scenarios reproduce their documented effects.

Each runs for a second with process names of its own.  The effects asserted are large and
robust (a lock wait of several milliseconds against under three, 0 misses against many, a
policy the thread read back from the kernel), never exact timings.  Settings are checked
against the kernel (sched_getattr through the results' `applied`, and `ps` in the mid-run
table), not against what the scenario asked for.
"""

from __future__ import annotations

import csv
import gzip
import json
import os
import signal
import statistics
import subprocess
import time

import pytest
import yaml
from kernelrun import finish, needs_rt, start_runner, thread

from runner.run.kernel import find_pids

pytestmark = [pytest.mark.kernel, needs_rt]

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TWO_CPUS = pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="the shipped scenario pins threads to CPU 1")


def run_file(tmp_path, path: str, *args: str):
    out = tmp_path / "out"
    done = finish(start_runner(path, "--out", str(out), "--settle", "0", "--duration", "1s", *args, cwd=str(tmp_path)), str(out))
    assert done.results is not None, done.err
    return done


def run_inline(tmp_path, scenario: dict, *args: str):
    path = tmp_path / f"{scenario['name']}.yaml"
    path.write_text(yaml.safe_dump(scenario, sort_keys=False))
    return run_file(tmp_path, str(path), *args)


def cell(results: dict, cell_id: str) -> int:
    return [c["id"] for c in results["cells"]].index(cell_id)


def event(t: dict, kind: str) -> dict:
    return next(e for e in t["events"] if e["kind"] == kind)


def activation_column(tmp_path, results: dict, cell_id: str, column: str) -> dict[str, list[int]]:
    """One column of a cell's samples file (a row per activation) of `run_file`'s run, by thread key."""
    c = results["cells"][cell(results, cell_id)]
    out: dict[str, list[int]] = {}
    with gzip.open(tmp_path / "out" / c["samples_file"], "rt", newline="") as handle:
        for row in csv.DictReader(handle):
            out.setdefault(row["thread"], []).append(int(row[column]))
    return out


def activation_text(tmp_path, results: dict, cell_id: str, column: str) -> dict[str, list[str]]:
    """One column of a cell's samples file as written (text), by thread key."""
    c = results["cells"][cell(results, cell_id)]
    out: dict[str, list[str]] = {}
    with gzip.open(tmp_path / "out" / c["samples_file"], "rt", newline="") as handle:
        for row in csv.DictReader(handle):
            out.setdefault(row["thread"], []).append(row[column])
    return out


def test_each_activation_says_how_long_it_waited_at_a_barrier_and_on_a_condition(tmp_path):
    # `lead` burns 3 ms, then meets `follower` at the barrier; `sender` burns 2 ms and signals `waiter`, who waits at once.
    # One named timer releases all four together (private timers start their grids at their first use, apart).
    timer = {"timer": "tick"}
    # The two that wait run at a higher priority, so they reach their wait at once on 2 CPUs.
    threads = [
        ("lead", "fifo:50", [timer, {"run": "3ms"}, {"barrier": "meet"}]),
        ("follower", "fifo:60", [timer, {"barrier": "meet"}]),
        ("waiter", "fifo:60", [timer, {"lock": "m"}, {"wait": {"cond": "go", "mutex": "m"}}, {"unlock": "m"}]),
        ("sender", "fifo:50", [timer, {"run": "2ms"}, {"signal": "go"}]),
    ]
    scenario = {
        "name": "activations",
        "resources": {
            "tick": {"kind": "timer", "period": "10ms"},
            "meet": {"kind": "barrier"},
            "m": {"kind": "mutex"},
            "go": {"kind": "cond"},
        },
        "processes": [
            {
                "name": "acts",
                "threads": [{"name": name, "sched": sched, "work": {"kind": "phases", "events": evs}} for name, sched, evs in threads],
            }
        ],
    }
    done = run_inline(tmp_path, scenario)
    res = done.results
    barrier = activation_column(tmp_path, res, "default", "barrier_wait_ns")
    cond = activation_column(tmp_path, res, "default", "cond_wait_ns")
    assert len(barrier["acts[0]/follower #2"]) > 50
    assert statistics.median(barrier["acts[0]/follower #2"]) > 2_000_000 > statistics.median(barrier["acts[0]/lead #1"])
    assert statistics.median(cond["acts[0]/waiter #3"]) > 1_000_000 and max(cond["acts[0]/sender #4"]) == 0
    assert max(activation_column(tmp_path, res, "default", "lock_wait_ns")["acts[0]/lead #1"]) == 0


@TWO_CPUS
def test_each_activation_says_how_long_it_waited_for_each_mutex_and_who_held_it(tmp_path):
    # One named timer releases all three. `taker` sleeps 0.3 ms (so both holders hold their mutex),
    # then waits for b (held by hold_b, on its CPU, 0.7 ms of its 1 ms section left) and then for a
    # (held by hold_a, on the other CPU, for 4 ms).
    threads = [
        ("hold_a", "fifo:50", 0, [{"timer": "tick"}, {"lock": "a"}, {"run": "4ms"}, {"unlock": "a"}]),
        ("hold_b", "fifo:50", 1, [{"timer": "tick"}, {"lock": "b"}, {"run": "1ms"}, {"unlock": "b"}]),
        ("taker", "fifo:60", 1, [{"timer": "tick"}, {"sleep": "300us"}, {"lock": "b"}, {"unlock": "b"}, {"lock": "a"}, {"unlock": "a"}]),
    ]
    scenario = {
        "name": "two_locks",
        "resources": {"tick": {"kind": "timer", "period": "20ms"}, "a": {"kind": "mutex"}, "b": {"kind": "mutex"}},
        "processes": [
            {
                "name": "locks",
                "threads": [
                    {"name": name, "sched": sched, "cpus": cpu, "work": {"kind": "phases", "events": evs}}
                    for name, sched, cpu, evs in threads
                ],
            }
        ],
    }
    done = run_inline(tmp_path, scenario)
    res = done.results
    c = res["cells"][0]
    rows = {}
    with gzip.open(tmp_path / "out" / c["samples_file"], "rt", newline="") as handle:
        for row in csv.DictReader(handle):
            rows.setdefault(row["thread"], []).append(row)
    taker = rows["locks[0]/taker #3"]
    waits = [json.loads(r["lock_waits"]) for r in taker]
    assert len(waits) > 30 and all(set(w) == {"a", "b"} for w in waits), waits[:3]
    # The per-mutex waits add up to the activation's lock wait, and each names the thread that held it.
    assert [w["a"]["wait_ns"] + w["b"]["wait_ns"] for w in waits] == [int(r["lock_wait_ns"]) for r in taker]
    assert sum(w["a"]["held_by"] == "locks[0]/hold_a #1" for w in waits) > len(waits) * 0.9
    assert sum(w["b"]["held_by"] == "locks[0]/hold_b #2" for w in waits) > len(waits) * 0.9
    a, b = statistics.median(w["a"]["wait_ns"] for w in waits), statistics.median(w["b"]["wait_ns"] for w in waits)
    assert a > 2_000_000 and 200_000 < b < a, (a, b)
    # A holder's own activations took their mutex, almost always without waiting.
    own = [json.loads(r["lock_waits"])["a"] for r in rows["locks[0]/hold_a #1"]]
    assert all(w["taken"] == 1 and w["held_by"] is None for w in own) and sum(w["contended"] for w in own) < len(own) * 0.1


@TWO_CPUS
def test_priority_inheritance_bounds_the_high_threads_lock_wait(tmp_path):
    # 2 s: about 100 activations of its 20 ms period, as the other programs get in 1 s
    done = run_file(tmp_path, os.path.join(REPO, "scenarios", "priority_inversion.yaml"), "--duration", "2s")
    res = done.results
    plain = thread(res, "high", cell(res, "protocol=none"))
    inherit = thread(res, "high", cell(res, "protocol=inherit"))
    # Without inheritance the wait spans medium's 5 ms burn; with it, only the rest of low's 2 ms section.
    assert plain["figures"]["lock_wait_ns"]["p50"] > 4_000_000
    assert inherit["figures"]["lock_wait_ns"]["p50"] < 3_000_000  # p50: a VM pause now and then is not what this is about
    for t in (plain, inherit):
        lock = event(t, "lock")
        assert lock["contended"] > 50 and [h["thread"] for h in lock["holders"]] == ["inversion/low #1"]
    assert done.code == 0, done.err
    # Per activation, in the samples file: each of high's activations waited as the aggregate says; low and medium never did.
    for cell_id, low_ms, high_ms in (("protocol=none", 4, 1000), ("protocol=inherit", 0, 3)):
        waits = activation_column(tmp_path, res, cell_id, "lock_wait_ns")
        high = waits["inversion[0]/high #3"]
        assert len(high) > 50 and low_ms * 1_000_000 < statistics.median(high) < high_ms * 1_000_000, (cell_id, high[:10])
        assert max(waits["inversion[0]/medium #2"]) == 0
        # low never waited 1 ms for the mutex: a longer lock event of low's is one it did not have to wait in
        # (not contended) but was preempted in (getrusage's involuntary switches): a VM stall that delayed low
        # past medium's release, 0.2 ms after its own, lets medium's 5 ms burn fall inside low's lock call.
        low = "inversion[0]/low #1"
        switched = activation_column(tmp_path, res, cell_id, "nivcsw")[low]
        per_mutex = [json.loads(r)["data"] for r in activation_text(tmp_path, res, cell_id, "lock_waits")[low]]
        long = [(w, m, n) for w, m, n in zip(waits[low], per_mutex, switched) if w >= 1_000_000]
        assert all(m["contended"] == 0 and n > 0 for _, m, n in long), (cell_id, long)
        # The private grids keep the offsets the delays give them, every period, whatever the jitter of the start.
        released = activation_column(tmp_path, res, cell_id, "scheduled_ns")
        lows = set(released[low])
        assert len(lows) > 50 and all(r - 500_000 in lows for r in released["inversion[0]/high #3"][:-1]), cell_id


def test_a_deadline_thread_keeps_its_runtime_where_an_other_one_misses(tmp_path):
    done = run_file(tmp_path, os.path.join(REPO, "scenarios", "deadline.yaml"))
    res = done.results
    dl = thread(res, "worker", cell(res, "sched=deadline:4ms/10ms/10ms"))
    other = thread(res, "worker", cell(res, "sched=other"))
    assert dl["applied"] == {**dl["applied"], "policy": "deadline", "runtime": 4_000_000, "deadline": 10_000_000, "period": 10_000_000}
    assert dl["figures"]["missed_releases"] == 0 and dl["figures"]["callbacks"] > 80
    assert other["figures"]["missed_releases"] > 10
    table = res["cells"][cell(res, "sched=deadline:4ms/10ms/10ms")]["thread_table"]
    assert [r["cls"] for r in table if r["comm"] == "worker"] == ["DLN"]


def _deadline_set(name: str, count: int, sched: str) -> dict:
    work = {"kind": "phases", "events": [{"timer": {"period": "10ms"}}, {"run": "1ms"}]}
    return {"name": name, "processes": [{"name": name, "threads": [{"name": "greedy", "count": count, "sched": sched, "work": work}]}]}


def test_a_deadline_set_the_machine_cannot_admit_is_refused_before_the_run_with_the_numbers(tmp_path):
    path = tmp_path / "dl_over.yaml"
    path.write_text(yaml.safe_dump(_deadline_set("dl_over", 3, "deadline:9ms/10ms/10ms"), sort_keys=False))
    done = finish(start_runner(str(path), "--out", str(tmp_path / "out"), cwd=str(tmp_path)), str(tmp_path / "out"))
    assert done.code == 2 and done.results is None
    assert "ask 2.70 CPUs of bandwidth" in done.err and "sched_rt_runtime_us" in done.err


def test_a_deadline_set_the_kernel_refuses_at_the_start_is_an_error_with_the_numbers(tmp_path):
    """Bandwidth another deadline task holds is the kernel's to know: the cell is an error, in numbers."""
    holder = subprocess.Popen(
        ["chrt", "-d", "--sched-runtime", "900000000", "--sched-deadline", "1000000000", "--sched-period", "1000000000", "0", "sleep", "30"]
    )
    try:
        time.sleep(0.2)
        done = run_inline(tmp_path, _deadline_set("dl_refused", 2, "deadline:6ms/10ms/10ms"))
    finally:
        holder.kill()
        holder.wait()
    c = done.results["cells"][0]
    assert c["status"] == "error" and done.code == 4
    assert "refused SCHED_DEADLINE admission (EBUSY)" in c["reason"] and "this cell asks 1.20 CPUs" in c["reason"]
    assert "sched_rt_runtime_us" in c["reason"] and "less what other deadline tasks hold" in c["reason"]


def test_a_chain_under_fifo_is_far_shorter_than_under_other(tmp_path):
    done = run_file(tmp_path, os.path.join(REPO, "scenarios", "pipeline.yaml"))
    res = done.results
    fifo = thread(res, "controller", cell(res, "sched=fifo:60"))["figures"]["chain_ns"]
    other = thread(res, "controller", cell(res, "sched=other"))["figures"]["chain_ns"]
    assert fifo["p50"] >= 2_000_000  # the chain's own work: 0.5 + 1 + 0.5 ms of CPU
    # Nine chains in ten under fifo stay within a millisecond of that work, and under other they stretch to twice it and
    # more.  Not p99, which in a 1 s cell (100 chains) is the worst chain or so: on the 2-CPU VM a FIFO wake-up waits for
    # its vCPU now and then, 4 to 8 ms with no preemption in the guest (the trace blames the hog that ran meanwhile),
    # and that took fifo's p99 past 4 ms in 2 of 10 runs.
    assert fifo["p90"] < 3_000_000 and other["p90"] > 2 * fifo["p90"]


def test_each_stage_of_a_chain_has_a_row_per_activation_with_its_chain_latency(tmp_path):
    done = run_file(tmp_path, os.path.join(REPO, "scenarios", "pipeline.yaml"), "--cell", "sched=fifo:60")
    res = done.results
    sensor, stage, controller = (thread(res, name) for name in ("sensor", "filter", "controller"))
    assert (sensor["released"], stage["released"], controller["released"]) == (False, True, True)
    for t in (stage, controller):
        f = t["figures"]
        # One activation per resume: as many as the sensor's callbacks (the last may be cut by the end of the run).
        assert sensor["figures"]["callbacks"] - 1 <= f["callbacks"] <= sensor["figures"]["callbacks"], t["name"]
        assert f["callbacks"] >= 80 and f["slack_ns"] is None and f["missed_releases"] == 0
        assert f["latency_ns"]["p50"] < 1_000_000, "a FIFO stage runs within a millisecond of its resume"
        assert f["callback_wall_ns"]["min"] >= 500_000, "each activation holds its stage's own work"
    chains = activation_column(tmp_path, res, "sched=fifo:60", "chain_ns")
    rows = chains["chain[0]/controller #3"]
    f = controller["figures"]
    # The rows and the native figure are the same measurements: one per activation, the same largest one.
    assert len(rows) == f["callbacks"] and max(rows) == f["chain_ns"]["max"] and min(rows) == f["chain_ns"]["min"]
    assert min(rows) >= 2_000_000, "end to end holds the three stages' 2 ms of work"
    c = res["cells"][0]
    with gzip.open(tmp_path / "out" / c["samples_file"], "rt", newline="") as handle:
        slack = {row["slack_ns"] for row in csv.DictReader(handle) if row["thread"] == "chain[0]/controller #3"}
    assert slack == {""}, "no period, no slack"


@TWO_CPUS
def test_each_phase_applies_its_policy_and_cpu_as_the_kernel_reports_on_entry(tmp_path):
    done = run_file(tmp_path, os.path.join(REPO, "scenarios", "phases.yaml"))
    mover = thread(done.results, "mover")
    quiet, urgent = mover["phases"]
    assert (quiet["applied"]["policy"], quiet["applied"]["cpus"], quiet["cpus_seen"]) == ("other", "0", [0])
    assert (urgent["applied"]["policy"], urgent["applied"]["priority"], urgent["applied"]["cpus"], urgent["cpus_seen"]) == (
        "fifo",
        50,
        "1",
        [1],
    )
    assert quiet["passes"] >= 200 and urgent["passes"] >= 200
    # A phase that comes back resumes the thread's release grid: before it did, the other phase's
    # time counted as missed releases (797 of 1,798); an OTHER phase on a busy CPU may still miss a few.
    f = mover["figures"]
    assert f["missed_releases"] < f["releases"] // 10


def test_phases_at_other_periods_measure_each_activation_against_its_own_timer(tmp_path):
    # rt-app's light/heavy pattern on the private timer (10 ms, then 20 ms), then a named 50 ms timer,
    # and back: before a thread's timers could differ, coming back to one counted the other phases'
    # time as its missed releases (65 of 112 for two named timers of 10 and 50 ms).
    phases = [
        {"name": "light", "loop": 5, "events": [{"timer": {"period": "10ms"}}, {"run": "1ms"}]},
        {"name": "heavy", "loop": 3, "events": [{"timer": {"period": "20ms"}}, {"run": "4ms"}]},
        {"name": "slow", "loop": 2, "events": [{"timer": "slow"}, {"run": "2ms"}]},
    ]
    scenario = {
        "name": "periods",
        "resources": {"slow": {"kind": "timer", "period": "50ms"}},
        "processes": [{"name": "prd", "main": {"sched": "fifo:50", "work": {"kind": "phases", "phases": phases}}}],
    }
    done = run_inline(tmp_path, scenario)
    f = thread(done.results, "prd")["figures"]
    assert done.code == 0, done.out
    assert f["callbacks"] >= 3 * 10 and f["missed_releases"] == 0 and f["overruns"] == 0
    key = thread(done.results, "prd")["key"]
    periods = activation_column(tmp_path, done.results, "default", "period_ns")[key]
    released = activation_column(tmp_path, done.results, "default", "scheduled_ns")[key]
    ended = activation_column(tmp_path, done.results, "default", "end_ns")[key]
    slack = activation_column(tmp_path, done.results, "default", "slack_ns")[key]
    cycle = [10_000_000] * 5 + [20_000_000] * 3 + [50_000_000] * 2
    assert periods == (cycle * (len(periods) // len(cycle) + 1))[: len(periods)], "each row carries the period of its timer event"
    for i in range(len(periods) - 1):
        private = periods[i] != 50_000_000 and periods[i + 1] != 50_000_000
        if private or periods[i] == periods[i + 1]:  # the next release on its own grid: the slack runs to it
            assert released[i + 1] - released[i] == periods[i + 1], "a grid advances by each timer event's own period"
            assert slack[i] == released[i + 1] - ended[i], (i, periods[i : i + 2])
        else:  # the next timer is another one: the slack runs to its own timer's next release
            assert slack[i] == released[i] + periods[i] - ended[i], (i, periods[i : i + 2])


def test_a_deadlock_ends_with_its_cell_as_an_error_naming_where_each_thread_stood(tmp_path):
    ab = [{"lock": "a"}, {"sleep": "20ms"}, {"lock": "b"}, {"unlock": "b"}, {"unlock": "a"}]
    ba = [{"lock": "b"}, {"sleep": "20ms"}, {"lock": "a"}, {"unlock": "a"}, {"unlock": "b"}]
    scenario = {
        "name": "deadlocked",
        "resources": {"a": {"kind": "mutex"}, "b": {"kind": "mutex"}},
        "processes": [
            {"name": "dl_first", "threads": [{"name": "ab", "work": {"kind": "phases", "events": ab}}]},
            {"name": "dl_second", "threads": [{"name": "ba", "work": {"kind": "phases", "events": ba}}]},
        ],
    }
    done = run_inline(tmp_path, scenario)
    c = done.results["cells"][0]
    assert c["status"] == "error" and done.code == 4
    assert "blocked in `lock b`" in c["reason"] and "blocked in `lock a`" in c["reason"]
    assert c["duration_ns"] < 10_000_000_000, "the deadlock ended with the cell"


def test_a_timer_thread_stuck_to_the_end_missed_every_release_it_did_not_serve(tmp_path):
    """A 10 ms timer thread deadlocked for the last 0.99 s counted `missed 0` of its releases."""
    ab = [{"timer": {"period": "10ms"}}, {"lock": "a"}, {"run": "1ms"}, {"lock": "b"}, {"unlock": "b"}, {"unlock": "a"}]
    ba = [{"timer": {"period": "10ms"}}, {"lock": "b"}, {"run": "1ms"}, {"lock": "a"}, {"unlock": "a"}, {"unlock": "b"}]
    scenario = {
        "name": "abba",
        "resources": {"a": {"kind": "mutex"}, "b": {"kind": "mutex"}},
        "processes": [
            {
                "name": "dl",
                "threads": [
                    {"name": "first", "sched": "fifo:40", "work": {"kind": "phases", "events": ab}},
                    {"name": "second", "sched": "fifo:40", "work": {"kind": "phases", "events": ba}},
                ],
            }
        ],
    }
    done = run_inline(tmp_path, scenario)
    assert done.results["cells"][0]["status"] == "error"
    for name in ("first", "second"):
        f = thread(done.results, name)["figures"]
        assert f["callbacks"] <= 2 and f["missed_releases"] >= 90 and f["releases"] == f["callbacks"] + f["missed_releases"], f


def test_a_timer_longer_than_the_cell_had_no_release_due_and_missed_none(tmp_path):
    """A 2 s housekeeping timer in a 1 s cell once counted 26,168 missed releases (its last release read as 0)."""
    scenario = {
        "name": "slowtimer",
        "processes": [
            {
                "name": "app",
                "threads": [
                    {"name": "fast", "work": {"kind": "phases", "events": [{"timer": {"period": "10ms"}}, {"run": "100us"}]}},
                    {"name": "housekeeping", "work": {"kind": "phases", "events": [{"timer": {"period": "2s"}}, {"run": "1ms"}]}},
                ],
            }
        ],
    }
    done = run_inline(tmp_path, scenario)
    assert done.results["cells"][0]["status"] == "passed", done.results["cells"][0]["reason"]
    f = thread(done.results, "housekeeping")["figures"]
    assert (f["callbacks"], f["missed_releases"], f["releases"]) == (0, 0, 0)


def test_a_deadlock_late_in_the_run_is_stuck_and_a_stage_waiting_as_ever_is_not(tmp_path):
    """A deadlock that began at 1.2 s of 2 s once ended `passed`: the rule was half the run blocked."""
    scenario = {
        "name": "latedeadlock",
        "duration": "2s",
        "resources": {"a": {"kind": "mutex"}, "b": {"kind": "mutex"}, "q": {"kind": "queue"}, "slow": {"kind": "queue"}},
        "processes": [
            {
                "name": "ld",
                "threads": [
                    {"name": "producer", "work": {"kind": "phases", "events": [{"timer": {"period": "10ms"}}, {"resume": "q"}]}},
                    {
                        "name": "consumer",
                        "work": {
                            "kind": "phases",
                            "events": [{"suspend": "q"}, {"lock": "b"}, {"run": "1ms"}, {"lock": "a"}, {"unlock": "a"}, {"unlock": "b"}],
                        },
                    },
                    {
                        "name": "maint",
                        "work": {
                            "kind": "phases",
                            "delay": "1200ms",
                            "loop": 1,
                            "events": [{"lock": "a"}, {"run": "15ms"}, {"lock": "b"}, {"unlock": "b"}, {"unlock": "a"}],
                        },
                    },
                    {"name": "ticker", "work": {"kind": "phases", "events": [{"timer": {"period": "300ms"}}, {"resume": "slow"}]}},
                    {"name": "stage", "work": {"kind": "phases", "events": [{"suspend": "slow"}, {"run": "1ms"}]}},
                ],
            }
        ],
    }
    done = run_inline(tmp_path, scenario, "--duration", "2s")
    c = done.results["cells"][0]
    assert c["status"] == "error" and done.code == 4, c["reason"]
    assert "ld/maint" in c["reason"] and "blocked in `lock b`" in c["reason"] and "blocked in `lock a`" in c["reason"]
    assert "ld/stage" not in c["reason"], "waiting up to 300 ms for its next release, as it always did"


def slow_consumer(name: str, process: str, queue: dict) -> dict:
    """A consumer 5 ms a resume behind a 2 ms producer."""
    return {
        "name": name,
        "resources": {"q": queue},
        "processes": [
            {
                "name": process,
                "threads": [
                    {
                        "name": "producer",
                        "sched": "fifo:40",
                        "work": {"kind": "phases", "events": [{"timer": {"period": "2ms"}}, {"resume": "q"}]},
                    },
                    {"name": "consumer", "sched": "fifo:30", "work": {"kind": "phases", "events": [{"suspend": "q"}, {"run": "5ms"}]}},
                ],
            }
        ],
    }


def test_a_stage_its_queue_drops_resumes_for_could_not_keep_up(tmp_path):
    """A consumer 5 ms a resume behind a 2 ms producer once passed, its 583 dropped resumes a warning only."""
    scenario = slow_consumer("slowconsumer", "sc", {"kind": "queue"})
    done = run_inline(tmp_path, scenario)
    c = done.results["cells"][0]
    consumer = thread(done.results, "consumer")["figures"]
    assert c["status"] == "failed" and done.code == 1, c["reason"]
    assert consumer["missed_releases"] > 100 and consumer["releases"] == consumer["callbacks"] + consumer["missed_releases"]
    failed = [(v["thread"], v["metric"]) for v in c["expectations"] if not v["passed"] and "consumer" in v["thread"]]
    assert failed == [("sc/consumer #2", "missed_releases")]  # (the producer may miss one on a busy machine: not the subject)
    # A pool of two behind one queue: its drops fail the cell as the pool's, charged to neither stage (once each got them all).
    scenario["processes"][0]["threads"][1].update(count=2, sched="other")  # beneath the producer, which then serves its timer
    (tmp_path / "pool").mkdir()
    pool = run_inline(tmp_path / "pool", {**scenario, "name": "pool"}).results
    c = pool["cells"][0]
    failed = [(v["thread"], v["metric"], v["measured"]) for v in c["expectations"] if not v["passed"] and "consumer" in v["thread"]]
    assert len(failed) == 1 and failed[0][:2] == ("sc/consumer-0 #2, sc/consumer-1 #3", "missed_releases") and failed[0][2] > 20
    assert [thread(pool, f"consumer-{i}")["figures"]["missed_releases"] for i in (0, 1)] == [0, 0]


def test_a_queue_that_drops_loses_the_resumes_nobody_waits_for_and_says_how_many(tmp_path):
    """rt-app's resume (pending: drop): a consumer 5 ms a resume behind a 2 ms producer takes only the resumes that come while
    it waits; the others are lost, counted on the resume event and said in the warnings, and it missed none (issue 40, 13).
    Kept (the queue's default), the same cell fails with hundreds of missed releases (the test above)."""
    scenario = slow_consumer("dropconsumer", "dc", {"kind": "queue", "pending": "drop"})
    done = run_inline(tmp_path, scenario)
    c = done.results["cells"][0]
    consumer, producer = thread(done.results, "consumer"), thread(done.results, "producer")
    resume = event(producer, "resume")
    assert consumer["figures"]["missed_releases"] == 0 and consumer["figures"]["callbacks"] > 50
    assert resume["lost"] > 100 and resume["count"] >= resume["lost"] + consumer["figures"]["callbacks"] - 1
    assert [w for w in c["warnings"] if w.startswith(f"queue q: {resume['lost']:,} resumes came while no thread was suspended")]
    assert not [v for v in c["expectations"] if not v["passed"] and "consumer" in v["thread"]], c["expectations"]


def test_a_resume_of_a_queue_that_drops_wakes_every_thread_suspended_on_it(tmp_path):
    """rt-app's resume is a broadcast: two threads suspended on one queue both run after each resume, where a queue that
    keeps its resumes gives each resume to one of them."""

    def scenario(pending: str) -> dict:
        return {
            "name": f"broadcast{pending}",
            "resources": {"q": {"kind": "queue", "pending": pending}},
            "processes": [
                {
                    "name": "bc",
                    "threads": [
                        {
                            "name": "producer",
                            "sched": "fifo:20",
                            "work": {"kind": "phases", "events": [{"timer": {"period": "10ms"}}, {"resume": "q"}]},
                        },
                        {
                            "name": "stage",
                            "count": 2,
                            "sched": "fifo:30",
                            "work": {"kind": "phases", "events": [{"suspend": "q"}, {"run": "200us"}]},
                        },
                    ],
                }
            ],
        }

    (tmp_path / "drop").mkdir()
    (tmp_path / "keep").mkdir()
    dropped = run_inline(tmp_path / "drop", scenario("drop")).results
    kept = run_inline(tmp_path / "keep", scenario("keep")).results
    resumes = event(thread(dropped, "producer"), "resume")["count"]
    assert resumes >= 50
    assert all(thread(dropped, f"stage-{i}")["figures"]["callbacks"] >= resumes - 2 for i in (0, 1))
    kept_resumes = event(thread(kept, "producer"), "resume")["count"]
    assert sum(thread(kept, f"stage-{i}")["figures"]["callbacks"] for i in (0, 1)) <= kept_resumes + 1


def test_threads_of_a_process_that_starts_in_order_begin_in_the_order_listed(tmp_path):
    """start: in_order (rt-app creates its threads in file order): each thread begins once the one listed before it has.

    Pinned to one CPU at rising FIFO priorities, threads that start together begin highest first (the list reversed);
    in order, they begin as listed, each after the one before it (issue 40, 14)."""

    def scenario(start: str) -> dict:
        threads = [
            {"name": f"t{i}", "sched": f"fifo:{10 + i}", "cpus": [0], "work": {"kind": "phases", "loop": 1, "events": [{"run": "1ms"}]}}
            for i in range(4)
        ]
        return {"name": f"order{start}", "processes": [{"name": "ord", "start": start, "threads": threads}]}

    (tmp_path / "in_order").mkdir()
    (tmp_path / "together").mkdir()
    ordered = run_inline(tmp_path / "in_order", scenario("in_order")).results
    together = run_inline(tmp_path / "together", scenario("together")).results
    began = [thread(ordered, f"t{i}")["began_ns"] for i in range(4)]
    assert all(b is not None for b in began) and began == sorted(began) and len(set(began)) == 4, began
    began = [thread(together, f"t{i}")["began_ns"] for i in range(4)]
    assert began[3] < began[0], began  # the contrast: together, the highest priority begins first


def test_a_stage_whose_backlog_grows_could_not_keep_up_before_its_queue_drops_one(tmp_path):
    """12 ms of work a resume behind a 10 ms producer: about 17 resumes queued at the end of 1 s, none dropped yet.

    It once passed.  A stage that serves a burst of three resumes per period within the period
    keeps up, though the end may find two of a burst still queued.
    """

    def scenario(name: str, run: str, resumes: int) -> dict:
        producer = [{"timer": {"period": "10ms"}}] + [{"resume": "q"}] * resumes
        return {
            "name": name,
            "resources": {"q": {"kind": "queue"}},
            "processes": [
                {
                    "name": "bk",
                    "threads": [
                        {"name": "producer", "sched": "fifo:40", "work": {"kind": "phases", "events": producer}},
                        {"name": "consumer", "sched": "fifo:30", "work": {"kind": "phases", "events": [{"suspend": "q"}, {"run": run}]}},
                    ],
                }
            ],
        }

    done = run_inline(tmp_path, scenario("backlog", "12ms", 1))
    c, consumer = done.results["cells"][0], thread(done.results, "consumer")["figures"]
    assert c["status"] == "failed" and done.code == 1, c["reason"]
    assert 5 <= consumer["missed_releases"] <= 30 and consumer["releases"] == consumer["callbacks"] + consumer["missed_releases"]
    failed = [v for v in c["expectations"] if not v["passed"] and "consumer" in v["thread"]]
    assert [v["metric"] for v in failed] == ["missed_releases"] and "could not keep up" in failed[0]["note"]
    for ends in ("1003ms", "1009ms"):  # 3 ms after a burst of three, two of them still queued; and after it was served
        (tmp_path / ends).mkdir()
        done = run_inline(tmp_path / ends, scenario("burst", "2ms", 3), "--duration", ends)
        consumer = thread(done.results, "consumer")["figures"]
        assert done.code == 0 and consumer["missed_releases"] == 0, done.results["cells"][0]["reason"]


def test_an_rt_app_file_runs_directly(tmp_path):
    done = run_file(tmp_path, os.path.join(REPO, "tests", "rtapp", "example2.json"), "--duration", "500ms")
    t = thread(done.results, "thread0")
    assert done.code == 0, done.err
    # run then timer: the last run has no release left to wait for in the run
    assert t["figures"]["callbacks"] >= 4 and event(t, "run")["count"] in (t["figures"]["callbacks"], t["figures"]["callbacks"] + 1)


def test_a_signal_wakes_an_rt_app_suspend_of_the_same_name(tmp_path):
    """rt-app's suspend waits on the condition of its name, which a signal of that name wakes: the waiter keeps pace."""
    done = run_file(tmp_path, os.path.join(REPO, "tests", "rtapp", "signal_wakes_suspend.json"))
    assert done.code == 0, done.err
    ticker, waiter = thread(done.results, "ticker"), thread(done.results, "waiter")
    assert ticker["figures"]["callbacks"] >= 90
    assert event(waiter, "run")["count"] >= ticker["figures"]["callbacks"] // 2, "woken by the ticker's signals"


def test_spawned_threads_are_created_mid_run_and_inherit_their_spawners_settings(tmp_path):
    done = run_file(tmp_path, os.path.join(REPO, "scenarios", "spawn.yaml"))
    res = done.results
    for cell_id, policy in (("inherit=true", "fifo"), ("inherit=false", "other")):
        c = res["cells"][cell(res, cell_id)]
        dispatcher = thread(res, "dispatcher", cell(res, cell_id))
        jobs = [t for t in c["threads"] if t["name"].startswith("job-")]
        assert len(jobs) == 8 and all(t["spawned"] for t in jobs)
        tids = {t["tid"] for t in jobs}
        assert len(tids) == 8 and 0 not in tids and dispatcher["tid"] not in tids
        assert {t["pid"] for t in jobs} == {dispatcher["pid"]}  # threads of the dispatcher's process, not processes
        # What each job read back from the kernel (sched_getattr) as it started: its creator's FIFO 60, or explicit defaults.
        assert {t["applied"]["policy"] for t in jobs} == {policy} and not any(t["degraded"] for t in jobs)
        for t in jobs:
            assert [(e["kind"], e["count"]) for e in t["events"]] == [("run", 1), ("iorun", 1)]
        spawn = event(dispatcher, "spawn")
        assert spawn["count"] == 8 and spawn["dropped"] == 0
        assert c["status"] == "passed" and not c["warnings"], c["warnings"]
    assert done.code == 0, done.err


def test_spawns_beyond_the_count_and_threads_never_spawned_are_reported(tmp_path):
    program = {"kind": "phases", "loop": 1, "events": [{"run": "1ms"}]}
    scenario = {
        "name": "spawn_limits",
        "duration": "1s",
        "processes": [
            {
                "name": "sp_limits",
                "threads": [
                    {
                        "name": "boss",
                        "work": {
                            "kind": "phases",
                            "loop": 3,
                            "events": [{"timer": {"period": "20ms"}}, {"spawn": "few"}, {"spawn": "many"}],
                        },
                    },
                    {"name": "sleeper", "work": {"kind": "phases", "loop": 1, "events": [{"sleep": "5s"}, {"spawn": "late"}]}},
                    {"name": "few", "spawned": True, "count": 2, "work": program},
                    {"name": "many", "spawned": True, "count": 4, "work": program},
                    {"name": "late", "spawned": True, "work": program},
                ],
            }
        ],
    }
    done = run_inline(tmp_path, scenario)
    c = done.results["cells"][0]
    boss = thread(done.results, "boss")
    few, many = (next(e for e in boss["events"] if e["event"] == f"spawn {n}") for n in ("few", "many"))
    assert (few["count"], few["dropped"], many["count"], many["dropped"]) == (2, 1, 3, 0)
    assert sorted(t["name"] for t in c["threads"] if t["spawned"]) == ["few-0", "few-1", "many-0", "many-1", "many-2"]
    assert any("1 `spawn few` found every instance taken" in w for w in c["warnings"]), c["warnings"]
    assert any("sp_limits/late: never spawned" in w for w in c["warnings"]), c["warnings"]
    assert not any("many" in w for w in c["warnings"]), c["warnings"]  # count is a bound: unused instances are fine


def test_a_waiter_takes_over_a_mutex_whose_holder_was_killed_and_the_cell_says_so(tmp_path):
    """The mutexes are robust: a worker killed while holding one leaves its waiter in another process free
    to take it (it used to wait on it to the end of the run, a plain lock of a barrier or queue for good)."""
    holder = [{"lock": "m"}, {"sleep": "5s"}, {"unlock": "m"}]
    waiter = [{"sleep": "200ms"}, {"lock": "m"}, {"unlock": "m"}, {"sleep": "5s"}]
    scenario = {
        "name": "died_holding",
        "resources": {"m": {"kind": "mutex"}},
        "processes": [
            {"name": "dieholder", "threads": [{"name": "holder", "work": {"kind": "phases", "events": holder}}]},
            {"name": "diewaiter", "threads": [{"name": "waiter", "work": {"kind": "phases", "events": waiter}}]},
        ],
    }
    path = tmp_path / "died_holding.yaml"
    path.write_text(yaml.safe_dump(scenario, sort_keys=False))
    out = tmp_path / "out"
    proc = start_runner(str(path), "--out", str(out), "--duration", "3s", "--no-trace", cwd=str(tmp_path))
    until = time.monotonic() + 15
    while not (pids := find_pids("dieholder")) and time.monotonic() < until:
        time.sleep(0.02)
    (pid,) = pids
    time.sleep(0.6)  # past the waiter's 200 ms: it waits on the held mutex
    os.kill(pid, signal.SIGKILL)
    done = finish(proc, str(out))
    assert done.results is not None, done.err
    c = done.results["cells"][0]
    lock = event(thread(done.results, "waiter"), "lock")
    assert lock["count"] == 1 and lock["spread_ns"]["max"] < 1_500_000_000, lock  # taken when its holder died, not at the end
    assert any("died holding it" in w and "mutex m" in w for w in c["warnings"]), c["warnings"]
