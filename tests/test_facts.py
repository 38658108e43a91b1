"""The system facts a run records (rteval's): gathered from the kernel, robust to what cannot be read, and stored.

The kernel tests compare every fact with the file or tool it comes from (/proc, /sys, ps,
taskset), never with the runner's own bookkeeping.  The pure tests check that facts that
cannot be read give None or an empty list and never an exception, and that results files
written before these facts existed still load.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time

import pytest
from reportdata import system_facts

from runner.results.document import MachineInfo, RunDocument
from runner.results.read import load
from runner.run import machine

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CPU = "/sys/devices/system/cpu"


def _text(path: str) -> str:
    with open(path) as handle:
        return handle.read().strip()


# ---------------------------------------------------------------- without the kernel


def test_facts_that_cannot_be_read_are_none_and_never_raise(monkeypatch):
    """Every file unreadable and /proc unlistable: the facts are None or empty, and gathering still returns."""
    monkeypatch.setattr(machine, "_read", lambda path: None)

    def unlistable(path: str) -> list[str]:
        raise PermissionError(13, "Permission denied", path)

    monkeypatch.setattr(machine.os, "listdir", unlistable)
    info = machine.machine_info()
    assert info.cmdline is None and info.clocksource is None and info.nohz_full_cpus is None
    assert info.smt_siblings == [] and info.cpufreq_governor_cpus == {}
    assert info.irqs == [] and info.irq_threads == []


def test_facts_skip_threads_and_files_that_vanish_or_are_garbled(monkeypatch):
    """A kernel thread that exits mid-read, a stat line cut short, a CPU list that is not one: left out, no exception."""
    files = {
        "/proc/2/task/2/children": "10 11 12 13",
        "/proc/10/stat": "10 (irq/9-acpi) S 2 0 0",  # cut short
        "/proc/11/stat": "11 (ksoftirqd/0) S " + " ".join(["0"] * 60),  # flags 0: not a kernel thread
        "/proc/12/stat": None,  # exited
        f"{CPU}/cpu0/topology/thread_siblings_list": "garbled",
        f"{CPU}/cpu1/topology/thread_siblings_list": "1",
        f"{CPU}/nohz_full": "(null)",
    }
    monkeypatch.setattr(machine, "_read", lambda path: files.get(path))
    assert machine.irq_threads() == []
    assert machine.smt_siblings((0, 1)) == ["1"]
    assert machine._nohz_full() == ""


def test_a_kernel_threads_stat_line_gives_its_scheduling(monkeypatch):
    """Fields 9 (flags), 40 (rt_priority) and 41 (policy) of /proc/PID/stat, as ps reads them; comm may hold spaces and parens."""

    def stat(pid: int, comm: str, flags: int, rtprio: int, policy: int) -> str:
        fields = ["0"] * 50
        fields[9 - 3], fields[40 - 3], fields[41 - 3] = str(flags), str(rtprio), str(policy)
        return f"{pid} ({comm}) " + " ".join(["S", *fields[1:]])

    files = {
        "/proc/2/task/2/children": "50 51 52",
        "/proc/50/stat": stat(50, "irq/24-ACPI:Ged", machine.PF_KTHREAD, 50, 1),
        "/proc/51/stat": stat(51, "ksoftirqd/1", machine.PF_KTHREAD | 0x40, 0, 0),
        "/proc/52/stat": stat(52, "irq/7-a) (b", machine.PF_KTHREAD, 99, 2),
    }
    monkeypatch.setattr(machine, "_read", lambda path: files.get(path))
    monkeypatch.setattr(machine.os, "sched_getaffinity", lambda pid: {0, 1, 3})
    got = [(t.pid, t.name, t.irq, t.policy, t.priority, t.cpus) for t in machine.irq_threads()]
    assert got == [
        (50, "irq/24-ACPI:Ged", 24, "fifo", 50, "0-1,3"),
        (51, "ksoftirqd/1", None, "other", 0, "0-1,3"),
        (52, "irq/7-a) (b", 7, "rr", 99, "0-1,3"),
    ]


def test_an_unknown_scheduling_policy_is_named_by_its_number():
    assert machine._policy_name(7) == "policy 7"  # SCHED_EXT, which this runner does not name
    assert machine._policy_name(6) == "deadline"


def test_results_without_the_facts_still_load_and_read_as_not_recorded(tmp_path):
    """A /2 file written before the facts existed: they load as None (not recorded), never as "none"."""
    for name in ("policy_matrix", "memory_lock"):
        doc = load(os.path.join(REPO, "tests", "data", name, "results.json"))
        m = doc.machine
        assert (m.cmdline, m.clocksource, m.smt_siblings, m.irqs, m.irq_threads, m.dma_latency) == (None,) * 6


def test_the_facts_round_trip_through_results_json(tmp_path):
    info = system_facts()
    path = str(tmp_path / "results.json")
    RunDocument(machine=info).save(path)
    assert load(path).machine == info
    stored = json.load(open(path))["machine"]
    assert stored["irq_threads"][2] == {"pid": 50, "name": "irq/24-ACPI:Ged", "irq": 24, "policy": "fifo", "priority": 50, "cpus": "0"}
    assert stored["dma_latency"] == {"requested_us": 0, "held": True, "reads_us": 0, "note": ""}


# ---------------------------------------------------------------- against the kernel


def test_memory_total_is_meminfos_memtotal_in_bytes_else_the_page_count(monkeypatch):
    """What psutil's virtual_memory().total gave, from /proc/meminfo: MemTotal in kB, times 1024."""
    meminfo = "MemTotal:       24641536 kB\nMemFree:         1000 kB\n"
    assert machine.memory_total(meminfo) == 24641536 * 1024
    assert machine.memory_total("MemFree: 1 kB\nMemTotal: 12 kB\n") == 12 * 1024
    monkeypatch.setattr(machine.os, "sysconf", {"SC_PHYS_PAGES": 3, "SC_PAGE_SIZE": 4096}.__getitem__)
    assert machine.memory_total(None) == 3 * 4096  # no /proc/meminfo: the page count
    assert machine.memory_total("MemTotal: lots\n") == 3 * 4096  # garbled: the page count

    def refused(name: str) -> int:
        raise ValueError(name)

    monkeypatch.setattr(machine.os, "sysconf", refused)
    assert machine.memory_total(None) is None


def test_memory_total_is_what_the_kernel_counts():
    with open("/proc/meminfo") as handle:
        kib = next(int(line.split()[1]) for line in handle if line.startswith("MemTotal:"))
    assert machine.machine_info().memory_total_bytes == kib * 1024


@pytest.fixture(scope="module")
def facts() -> MachineInfo:
    return machine.machine_info()


@pytest.mark.kernel
def test_facts_cmdline_clocksource_and_cpu_sets_are_the_kernels(facts):
    assert facts.cmdline == _text("/proc/cmdline")
    assert facts.clocksource == _text("/sys/devices/system/clocksource/clocksource0/current_clocksource")
    assert facts.isolated_cpus == _text(f"{CPU}/isolated")
    if os.path.exists(f"{CPU}/nohz_full"):
        assert facts.nohz_full_cpus == _text(f"{CPU}/nohz_full").replace("(null)", "")
    else:
        assert facts.nohz_full_cpus is None


@pytest.mark.kernel
def test_facts_smt_siblings_cover_every_online_cpu_once(facts):
    online = machine._cpus(_text(f"{CPU}/online"))
    assert facts.smt_siblings is not None
    groups = [machine._cpus(g) for g in facts.smt_siblings]
    assert sorted(c for g in groups for c in g) == sorted(online)
    for group in groups:
        for cpu in group:
            assert machine._cpus(_text(f"{CPU}/cpu{cpu}/topology/thread_siblings_list")) == group


@pytest.mark.kernel
def test_facts_governor_per_cpu_is_the_kernels(facts):
    online = machine._cpus(_text(f"{CPU}/online"))
    want: dict[int, str] = {}
    for cpu in online:
        path = f"{CPU}/cpu{cpu}/cpufreq/scaling_governor"
        if os.path.exists(path):
            want[cpu] = _text(path)
    got = {cpu: governor for governor, cpus in (facts.cpufreq_governor_cpus or {}).items() for cpu in machine._cpus(cpus)}
    assert got == want
    assert facts.cpufreq_governors == sorted(set(want.values()))


@pytest.mark.kernel
def test_facts_irqs_are_the_kernels_affinity_and_proc_interrupts_names(facts):
    assert facts.irqs is not None
    lines = {}
    with open("/proc/interrupts") as handle:
        for line in handle.read().splitlines()[1:]:
            head, _, rest = line.partition(":")
            if head.strip().isdigit():
                lines[int(head)] = rest.rstrip()
    for irq in facts.irqs:
        assert irq.affinity == _text(f"/proc/irq/{irq.irq}/smp_affinity_list")
        if os.path.exists(f"/proc/irq/{irq.irq}/effective_affinity_list"):
            assert irq.effective == _text(f"/proc/irq/{irq.irq}/effective_affinity_list")
        if irq.irq in lines:  # it may have been freed since; an IRQ /proc/interrupts shows ends with its handlers
            assert irq.name and lines[irq.irq].endswith(irq.name), (irq, lines[irq.irq])
    listed = {irq.irq for irq in facts.irqs}
    for number in set(lines) - listed:  # what /proc/interrupts shows and the facts leave out has no handler
        assert not os.path.exists(f"/proc/irq/{number}") or _text(f"/sys/kernel/irq/{number}/actions") == "", number


@pytest.mark.kernel
@pytest.mark.skipif(not shutil.which("ps"), reason="needs ps")
def test_facts_irq_threads_are_what_ps_and_taskset_say(facts):
    ps = subprocess.run(["ps", "-e", "-o", "pid=,cls=,rtprio=,comm="], capture_output=True, text=True, check=True).stdout
    rows = {}
    for line in ps.splitlines():
        pid, cls, rtprio, comm = line.split(None, 3)
        if comm.startswith(("irq/", "ksoftirqd/")):
            rows[int(pid)] = (cls, rtprio, comm)
    ours = {t.pid: t for t in facts.irq_threads or []}
    assert set(ours) == set(rows)  # kernel threads do not come and go during a test
    cls_of = {"other": "TS", "fifo": "FF", "rr": "RR", "batch": "B", "idle": "IDL", "deadline": "DLN"}
    for pid, (cls, rtprio, comm) in rows.items():
        t = ours[pid]
        assert cls_of[t.policy] == cls and (str(t.priority) if t.policy in ("fifo", "rr") else "-") == rtprio
        assert comm.startswith(t.name[:15]) or t.name.startswith(comm)
        taskset = subprocess.run(["taskset", "-pc", str(pid)], capture_output=True, text=True, check=True).stdout
        assert taskset.rsplit(":", 1)[1].strip() == t.cpus
    online = machine._cpus(_text(f"{CPU}/online"))
    assert sum(t.name.startswith("ksoftirqd/") for t in ours.values()) == len(online)  # one per CPU, always


@pytest.mark.kernel
def test_facts_a_user_process_named_like_an_irq_thread_is_not_one(monkeypatch):
    """Without kthreadd's children list every process is looked at: a user process called `irq/99-fake` is left out."""
    code = "open('/proc/self/comm', 'w').write('irq/99-fake'); import time; print('ready', flush=True); time.sleep(30)"
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline() == "ready\n"
        real = machine._read
        monkeypatch.setattr(machine, "_read", lambda path: None if path == "/proc/2/task/2/children" else real(path))
        scanned = machine.irq_threads()
        assert proc.pid not in {t.pid for t in scanned}
        monkeypatch.undo()
        assert [(t.pid, t.name) for t in scanned] == [(t.pid, t.name) for t in machine.irq_threads()]
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.kernel
def test_facts_gathering_takes_under_50_ms():
    machine.machine_info()  # imports and caches warm, as in a run
    best = min(_timed(machine.machine_info) for _ in range(5))
    assert best < 0.050, f"gathering the machine's facts took {best * 1e3:.1f} ms"


def _timed(call: object) -> float:
    start = time.perf_counter()
    call()  # type: ignore[operator]
    return time.perf_counter() - start
