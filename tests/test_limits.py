"""Machine limits are checked at validate time, against fake limits here: nothing is read from this machine."""

from __future__ import annotations

import os

import pytest
from conftest import run_cli

from runner.errors import ScenarioError
from runner.scenario import limits as lim
from runner.scenario.loader import parse_scenario
from runner.scenario.yamlsource import load_text

ROOMY = lim.MachineLimits(
    pid_max=4_194_304, threads_max=1_000_000, memlock=None, cap_ipc_lock=True, mem_available=64 << 30, cpus=(0, 1, 2, 3)
)


def problems(text: str, machine: lim.MachineLimits | None) -> list[str]:
    try:
        parse_scenario(load_text(text, "s.yaml"), machine)
    except ScenarioError as exc:
        return [str(p) for p in exc.problems]
    return []


MANY_THREADS = "name: x\nprocesses:\n  - name: app\n    instances: 64\n    threads:\n" + "".join(
    f"      - {{name: t{i}, count: 1024}}\n" for i in range(8)
)


def test_thread_count_is_checked_against_pid_max_of_this_machine():
    small = lim.MachineLimits(pid_max=32768, threads_max=192_000, threads_running=100)
    found = problems(MANY_THREADS, small)
    assert found == [
        (
            "s.yaml:3:3: processes: the cell needs 524360 threads (instances x threads, hogs and the runner's own 8), "
            "but on this machine (pid_max 32768, 100 threads running) at most 32668 can start; lower count or instances"
        )
    ]


def test_the_smallest_thread_limit_is_named():
    text = "name: x\nprocesses:\n  - name: app\n    threads: [{name: w, count: 100}]\nbackground:\n  hogs: [{count: 4, kind: thread}]\n"
    assert problems(text, lim.MachineLimits(pid_max=4_194_304, threads_max=120, threads_running=10))[0].endswith(
        "(threads-max 120, 10 threads running) at most 110 can start; lower count or instances"
    )
    assert "RLIMIT_NPROC 64" in problems(text, lim.MachineLimits(nproc=64))[0]
    assert "cgroup pids.max 50" in problems(text, lim.MachineLimits(cgroup_pids_max=50))[0]
    assert problems(text, ROOMY) == []


def test_without_machine_limits_the_fixed_ceiling_still_holds():
    assert problems(MANY_THREADS, None) == [
        "s.yaml:3:3: processes: the cell creates 524352 threads (instances x threads, and hogs); at most 131072 threads in a cell"
    ]


LOCKED = "name: x\nprocesses:\n  - name: app\n    memory: {lock: true, prealloc: 100GiB}\n    threads: [{name: t, count: 2}]\n"


def test_locked_prealloc_beyond_rlimit_memlock_is_refused_even_for_root_without_cap_ipc_lock():
    # root in a container: uid 0 but no CAP_IPC_LOCK, so RLIMIT_MEMLOCK applies (read() keeps it)
    found = problems(LOCKED, lim.MachineLimits(memlock=8 << 20, mem_available=256 << 30))
    assert found == [
        (
            "s.yaml:4:13: processes[0].memory: process app locks its memory: prealloc 100GiB and 2 thread stacks pin "
            "at least 100.0GiB, but on this machine RLIMIT_MEMLOCK is 8MiB and the runner has no CAP_IPC_LOCK; lower "
            "prealloc (or stack_size), or raise the limit ('ulimit -l unlimited', 'memlock unlimited' in "
            "/etc/security/limits.conf)"
        )
    ]


def test_unlimited_memlock_leaves_ram_as_the_bound():
    found = problems(LOCKED, lim.MachineLimits(memlock=None, cap_ipc_lock=True, mem_available=16 << 30))
    assert found == [
        (
            "s.yaml:3:3: processes: the cell keeps 100.0GiB resident (prealloc, locked stacks, per-callback alloc, "
            "and programs' mem buffers and allocs, times instances and counts), but on this machine MemAvailable is "
            "16GiB; lower prealloc, alloc, mem, count or instances"
        )
    ]
    assert problems(LOCKED, lim.MachineLimits(mem_available=200 << 30)) == []


def test_per_callback_alloc_counts_against_ram_with_instances_and_counts():
    text = (
        "name: x\nprocesses:\n  - name: app\n    instances: 4\n    threads:\n"
        "      - {name: a, count: 8, work: {kind: periodic, period: 100ms, alloc: 1GiB}}\n"
    )
    assert "keeps 32GiB resident" in problems(text, lim.MachineLimits(mem_available=31 << 30))[0]
    assert problems(text, lim.MachineLimits(mem_available=33 << 30)) == []


@pytest.mark.parametrize(
    ("events", "per_thread"),
    [
        ("[{mem: 1GiB}, {sleep: 1ms}]", 1 << 30),  # the buffer mem writes stays resident
        ("[{alloc: 2GiB}, {sleep: 1ms}]", 2 << 30),  # touched whole, then freed: its peak counts
        ("[{mem: 1GiB}, {mem: 512MiB}, {alloc: 1GiB}, {alloc: 256MiB}]", 2 << 30),  # one buffer, the largest of each
        ("[{iorun: 512MiB}, {sleep: 1ms}]", 1 << 20),  # iorun writes from the buffer in 1 MiB chunks
    ],
)
def test_programs_mem_and_alloc_events_count_against_ram_with_instances_and_counts(events, per_thread):
    """A phases program's `alloc: 100GiB` once validated on a 21 GiB machine: a run would have met the OOM killer."""
    thread = f"{{name: t, count: 4, work: {{kind: phases, events: {events}}}}}"
    text = f"name: x\nprocesses:\n  - name: app\n    instances: 2\n    threads:\n      - {thread}\n"
    total = 8 * per_thread
    assert "resident" in problems(text, lim.MachineLimits(mem_available=total - 1))[0]
    assert problems(text, lim.MachineLimits(mem_available=total + 1)) == []


def test_cpus_outside_this_machine_are_refused():
    text = "name: x\nprocesses:\n  - name: app\n    main: {cpus: [1, 7]}\n    threads: [{name: t, cpus: 2-3}]\n"
    assert problems(text, lim.MachineLimits(cpus=(0, 1))) == [
        "s.yaml:4:18: processes[0].main.cpus: CPU 7 is not available on this machine (the runner may use 0-1)",
        "s.yaml:5:31: processes[0].threads[0].cpus: CPUs 2-3 are not available on this machine (the runner may use 0-1)",
    ]


def test_a_limit_problem_in_some_cells_names_them():
    text = (
        "name: x\nmatrix:\n  prealloc: [0B, 1MiB, 2GiB]\nprocesses:\n  - name: app\n"
        "    memory: {lock: true, prealloc: '${{ matrix.prealloc }}'}\n"
    )
    found = problems(text, lim.MachineLimits(memlock=64 << 20))
    assert len(found) == 1 and found[0].endswith("(in cell prealloc=2GiB)")


def test_read_gives_plausible_facts_of_this_machine():
    facts = lim.MachineLimits.read()
    assert facts.pid_max is None or facts.pid_max >= 300
    assert facts.mem_available is None or facts.mem_available > 0
    assert facts.cpus is None or len(facts.cpus) >= 1
    assert facts.default_stack > 0
    assert facts.memlock is None or not facts.cap_ipc_lock


@pytest.mark.parametrize("nbytes, text", [(8 << 20, "8MiB"), (24_825_675_776, "23.1GiB"), (100, "100B")])
def test_approx_size(nbytes, text):
    assert lim.approx_size(nbytes) == text


def test_a_cpu_the_machine_lacks_is_a_warning_of_validate_and_an_error_of_a_run():
    """A file written for a bigger machine is valid: `runner validate` warns, a run or --list here refuses."""
    text = "name: x\nprocesses:\n  - name: app\n    main: {cpus: 7}\n    threads: [{name: t, cpus: 1}]\n"
    machine = lim.MachineLimits(cpus=(0,), online=(0, 1))
    doc = load_text(text, "s.yaml")
    loaded = parse_scenario(doc, machine, for_run=False)
    assert [str(w) for w in loaded.warnings] == [
        "s.yaml:4:18: warning: processes[0].main.cpus: CPU 7 does not exist on this machine (CPUs 0-1); "
        "the file is valid, but it cannot run here",
        "s.yaml:5:31: warning: processes[0].threads[0].cpus: CPU 1 is outside the CPUs the runner may use "
        "(0: it runs under taskset or in a cpuset); the file is valid, but it cannot run here",
    ]
    assert problems(text, machine) == [
        "s.yaml:4:18: processes[0].main.cpus: CPU 7 does not exist on this machine (CPUs 0-1)",
        "s.yaml:5:31: processes[0].threads[0].cpus: CPU 1 is outside the CPUs the runner may use (0: it runs under taskset or in a cpuset)",
    ]


def test_validate_warns_and_list_refuses_a_cpu_beyond_the_machine(tmp_path):
    path = tmp_path / "big.yaml"
    path.write_text(f"name: big\nprocesses:\n  - name: app\n    main: {{cpus: {max(os.sched_getaffinity(0)) + 1000}}}\n")
    outcome = run_cli("validate", str(path))
    assert outcome.code == 0 and "warning: processes[0].main.cpus: CPU" in outcome.err and "ok (1 cell)" in outcome.out
    outcome = run_cli(str(path), "--list")
    assert outcome.code == 2 and "does not exist on this machine" in outcome.err and outcome.out == ""


def test_deadline_bandwidth_past_what_this_machine_admits_is_refused_before_the_run():
    """Three threads of 9 ms/10 ms on 2 CPUs once ran their whole cell with the policy refused (EBUSY)."""
    text = (
        "name: x\nmatrix:\n  runtime: [4ms, 9ms]\nprocesses:\n  - name: dlo\n    threads:\n"
        "      - {name: greedy, count: 3, sched: 'deadline:${{ matrix.runtime }}/10ms/10ms'}\n"
    )
    two = lim.MachineLimits(online=(0, 1), rt_runtime_us=950_000, rt_period_us=1_000_000)
    found = problems(text, two)
    assert len(found) == 1 and "ask 2.70 CPUs of bandwidth (greedy 0.90, greedy 0.90, greedy 0.90)" in found[0]
    assert "admits at most 0.95 per CPU x 2 CPUs = 1.90" in found[0] and found[0].endswith("(in cell runtime=9ms)")
    assert problems(text, lim.MachineLimits(online=(0, 1, 2), rt_runtime_us=950_000, rt_period_us=1_000_000)) == []
    assert problems(text, lim.MachineLimits(online=(0, 1), rt_runtime_us=-1, rt_period_us=1_000_000)) == [], "no limit"
