"""Machine limits and this user's rights, checked against fake limits here: nothing is read from this machine.

What this machine lacks refuses a run (exit 2) and is a warning of validate, --list and imports; what this user may
not do is a warning there too, and a run leaves it to its preflight (exit 3)."""

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
THREADS_65K = MANY_THREADS.replace("instances: 64", "instances: 8")


def warnings(text: str, machine: lim.MachineLimits) -> list[str]:
    """What `runner validate` (and --list, import-rtapp) says of `text` on `machine`: warnings only, the file is valid."""
    return [str(w) for w in parse_scenario(load_text(text, "s.yaml"), machine, for_run=False).warnings]


def test_thread_count_is_checked_against_pid_max_of_this_machine():
    small = lim.MachineLimits(pid_max=32768, threads_max=192_000, threads_running=100)
    found = problems(THREADS_65K, small)
    words = (
        "s.yaml:3:3: processes: the cell needs 65552 threads (instances x threads, hogs and the runner's own 8), "
        "but on this machine (pid_max 32768, 100 threads running) at most 32668 can start; lower count or instances"
    )
    assert found == [words], "a run here is refused"
    assert warnings(THREADS_65K, small) == [
        words.replace(": processes:", ": warning: processes:") + "; the file is valid, but it cannot run here"
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


def test_locked_memory_beyond_rlimit_memlock_is_a_warning_and_left_to_the_runs_preflight_whatever_its_size():
    """Issue 40: as an ordinary user (RLIMIT_MEMLOCK 8 MiB, no CAP_IPC_LOCK) memory_lock.yaml's --list and validate failed
    (exit 2, invalid input), and a run was exit 2 or 3 by the size asked.  A right is no property of the file: validate
    warns; a run leaves it to the preflight, which refuses it with how to grant it (exit 3) whatever the size."""
    machine = lim.MachineLimits(memlock=8 << 20, mem_available=256 << 30)  # root in a container: no CAP_IPC_LOCK
    assert warnings(LOCKED, machine) == [
        "s.yaml:4:13: warning: processes[0].memory: process app locks its memory: prealloc 100GiB and 2 thread stacks pin "
        "about 100.1GiB with the interpreter, but on this machine RLIMIT_MEMLOCK is 8MiB and this user has no CAP_IPC_LOCK; "
        "a run here is refused (exit 3) unless it gets the right ('ulimit -l unlimited', 'memlock unlimited' in "
        "/etc/security/limits.d/, README, Permissions) or --allow-degraded"
    ]
    assert problems(LOCKED, machine) == [], "not invalid input for a run either: its preflight says exit 3"
    small = LOCKED.replace("100GiB", "1MiB")
    assert len(warnings(small, machine)) == 1 and problems(small, machine) == []


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
    found = warnings(text, lim.MachineLimits(memlock=128 << 20))
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
    """A file written for a bigger machine is valid: `runner validate` and --list warn, a run here refuses."""
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


def test_validate_and_list_warn_and_a_run_refuses_a_cpu_beyond_the_machine(tmp_path):
    path = tmp_path / "big.yaml"
    path.write_text(f"name: big\nprocesses:\n  - name: app\n    main: {{cpus: {max(os.sched_getaffinity(0)) + 1000}}}\n")
    outcome = run_cli("validate", str(path))
    assert outcome.code == 0 and "warning: processes[0].main.cpus: CPU" in outcome.err and "ok (1 cell)" in outcome.out
    outcome = run_cli(str(path), "--list")
    assert outcome.code == 0 and "warning: processes[0].main.cpus: CPU" in outcome.err and "app" in outcome.out
    outcome = run_cli(str(path), "--out", str(tmp_path / "r"))
    assert outcome.code == 2 and "does not exist on this machine" in outcome.err and "warning" not in outcome.err
    assert not (tmp_path / "r").exists()


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


RIGHTS = (
    "name: x\nprocesses:\n  - name: app\n    main: {sched: 'fifo:80'}\n    threads:\n"
    "      - {name: dl, sched: 'deadline:1ms/10ms'}\n      - {name: nice, sched: {policy: other, nice: -5}}\n"
    "      - name: ph\n        work:\n          kind: phases\n          phases:\n"
    "            - {name: up, sched: 'fifo:99', cpus: 7, events: [{run: 1ms}]}\n"
    "background:\n  hogs: [{count: 1, sched: 'rr:10'}]\n"
)


def test_rights_this_user_lacks_and_priority_99_are_warnings_where_written_and_no_error_of_a_run():
    """Issue 40: validate said ok to fifo:99 that a run refuses, and to RT settings this user may not set."""
    user = lim.MachineLimits(rtprio=0, nice_limit=0, cap_sys_nice=False, cpus=(0, 1), online=(0, 1))
    refused = "a run here is refused (exit 3) unless this user gets the right (README, Permissions) or --allow-degraded"
    assert warnings(RIGHTS, user) == [
        "s.yaml:12:50: warning: processes[0].threads[2].work.phases[0].cpus: CPU 7 does not exist on this machine (CPUs 0-1); "
        "the file is valid, but it cannot run here",
        "s.yaml:4:19: warning: processes[0].main.sched: app/app asks for fifo:80, but on this machine this user has RLIMIT_RTPRIO 0 "
        f"and no CAP_SYS_NICE; {refused}",
        "s.yaml:6:27: warning: processes[0].threads[0].sched: app/dl asks for SCHED_DEADLINE, which needs CAP_SYS_NICE (no limit "
        f"grants it), and this user has not it; {refused}",
        "s.yaml:7:29: warning: processes[0].threads[1].sched: app/nice asks for nice -5, which needs CAP_SYS_NICE or RLIMIT_NICE 25, "
        f"but on this machine this user has RLIMIT_NICE 0 and no CAP_SYS_NICE; {refused}",
        "s.yaml:12:33: warning: processes[0].threads[2].work.phases[0].sched: app/ph phase up asks for RT priority 99, the runner "
        "watchdog's own; a run refuses it unless --allow-priority-99 (the runner may then be unable to stop a runaway thread); use "
        "98 or less",
        "s.yaml:12:33: warning: processes[0].threads[2].work.phases[0].sched: app/ph phase up asks for fifo:99, but on this machine "
        f"this user has RLIMIT_RTPRIO 0 and no CAP_SYS_NICE; {refused}",
        "s.yaml:14:28: warning: background.hogs[0].sched: background hog hog asks for rr:10, but on this machine this user has "
        f"RLIMIT_RTPRIO 0 and no CAP_SYS_NICE; {refused}",
    ]
    assert problems(RIGHTS, user) == [
        "s.yaml:12:50: processes[0].threads[2].work.phases[0].cpus: CPU 7 does not exist on this machine (CPUs 0-1)"
    ], "a run leaves rights and priority 99 to its preflight; a CPU the machine lacks is its own refusal (exit 2)"
    root = lim.MachineLimits(cpus=(0, 1, 2, 3, 4, 5, 6, 7))
    assert [w.split(": ", 3)[2] for w in warnings(RIGHTS, root)] == ["processes[0].threads[2].work.phases[0].sched"], "99 only"
