"""The placement rule, without processes: RT threads against higher-priority interrupt threads and isolated CPUs."""

from __future__ import annotations

import pytest
from reportdata import main_thread, matrix

from runner.report.placement import placement_warnings
from runner.results.document import IrqThread, MachineInfo, ThreadResult
from runner.scenario.model import Policy
from runner.scenario.plan import Settings


def _thread(policy: Policy = Policy.FIFO, priority: int = 10, cpus: tuple[int, ...] | None = None, gone: bool = False) -> ThreadResult:
    t = main_thread(next(c for c in matrix().cells if c.id == "policy=fifo,priority=10"))
    return t.model_copy(update={"applied": None if gone else Settings(policy, priority, 0, cpus)})


def _irq(name: str, cpus: str, policy: str = "fifo", priority: int = 50, irq: int | None = 24) -> IrqThread:
    return IrqThread(pid=100, name=name, irq=irq, policy=policy, priority=priority, cpus=cpus)


SOFTIRQ = [_irq("ksoftirqd/0", "0", "other", 0, None), _irq("ksoftirqd/1", "1", "other", 0, None)]


def _machine(*irq_threads: IrqThread, isolated: str = "", online: str | None = "0-3") -> MachineInfo:
    return MachineInfo(cpus_online=online, isolated_cpus=isolated, irq_threads=[*SOFTIRQ, *irq_threads])


def test_placement_an_rt_thread_below_an_irq_thread_on_its_cpu_is_warned():
    t = _thread(priority=10, cpus=(0, 1))
    [warning] = placement_warnings(_machine(_irq("irq/24-ACPI:Ged", "0")), [t])
    assert warning.thread == t.key
    assert warning.words == (
        "at FIFO 10 on CPUs 0-1 shares them with 1 interrupt thread of higher RT priority, which preempts it whenever its "
        "interrupt fires: irq/24-ACPI:Ged (FIFO 50, CPU 0); raise its priority above theirs, or move it or the interrupts "
        "(smp_affinity_list)"
    )


@pytest.mark.parametrize(
    ("thread", "irq"),
    [
        (_thread(priority=80, cpus=(0,)), _irq("irq/24-x", "0")),  # above the IRQ thread
        (_thread(priority=50, cpus=(0,)), _irq("irq/24-x", "0")),  # the same priority does not preempt a FIFO thread
        (_thread(priority=10, cpus=(1,)), _irq("irq/24-x", "0")),  # another CPU
        (_thread(Policy.OTHER, 0, (0,)), _irq("irq/24-x", "0")),  # not an RT thread
        (_thread(Policy.BATCH, 0, None), _irq("irq/24-x", "0-3")),
        (_thread(gone=True), _irq("irq/24-x", "0-3")),  # no applied settings: the thread was gone
        (_thread(priority=1, cpus=(0,)), _irq("irq/24-x", "0", "other", 0)),  # a threaded IRQ at SCHED_OTHER
    ],
)
def test_placement_no_warning_when_nothing_of_higher_priority_shares_the_cpu(thread, irq):
    assert placement_warnings(_machine(irq), [thread]) == []


def test_placement_facts_a_run_did_not_record_give_no_warning():
    assert placement_warnings(MachineInfo(cpus_online="0-3", isolated_cpus=""), [_thread(priority=1)]) == []


def test_placement_an_unpinned_thread_may_run_on_every_online_cpu_and_rr_counts_as_rt():
    [warning] = placement_warnings(_machine(_irq("irq/30-nvme0q1", "3", "rr", 60, 30)), [_thread(Policy.RR, 20, None)])
    assert warning.words.startswith("at RR 20 on CPUs 0-3 shares them with 1 interrupt thread")
    assert "irq/30-nvme0q1 (RR 60, CPU 3)" in warning.words


def test_placement_many_irq_threads_are_counted_highest_first():
    irqs = [_irq(f"irq/{n}-eth0", str(n % 2), "fifo", 20 + n, n) for n in range(30, 37)]
    [warning] = placement_warnings(_machine(*irqs), [_thread(priority=10, cpus=(0, 1))])
    assert "7 interrupt threads of higher RT priority, which preempt it whenever their interrupt fires" in warning.words
    assert "irq/36-eth0 (FIFO 56, CPU 0), irq/35-eth0 (FIFO 55, CPU 1)" in warning.words and "3 more;" in warning.words


@pytest.mark.parametrize(
    ("cpus", "want"),
    [
        ((0, 1), "at FIFO 80 is pinned on CPUs 0-1, outside the isolated CPUs 2-3 (CPUs 0-1)"),
        ((1, 2), "at FIFO 80 is pinned on CPUs 1-2, outside the isolated CPUs 2-3 (CPU 1)"),
        (None, "at FIFO 80 is not pinned and may run on CPUs 0-3, outside the isolated CPUs 2-3 (CPUs 0-1)"),
        ((2, 3), None),
        ((3,), None),
    ],
)
def test_placement_an_rt_thread_outside_the_isolated_cpus_is_warned(cpus, want):
    got = placement_warnings(_machine(isolated="2-3"), [_thread(priority=80, cpus=cpus)])
    assert [w.words.split(":")[0] for w in got] == ([want] if want else [])


def test_placement_without_isolated_cpus_there_is_nothing_to_be_outside_of():
    assert placement_warnings(_machine(isolated=""), [_thread(priority=80, cpus=(0,))]) == []


def test_placement_an_unknown_cpu_set_is_taken_as_every_cpu():
    """A run that recorded no online CPUs: an unpinned thread still shares every interrupt thread's CPU."""
    [warning] = placement_warnings(_machine(_irq("irq/24-x", "0"), online=None), [_thread(priority=10)])
    assert warning.words.startswith("at FIFO 10 on every CPU shares them with 1 interrupt thread")
