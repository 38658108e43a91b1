"""The system facts and placement warnings in the report, rendered from recorded results with facts added."""

from __future__ import annotations

import copy

import pytest
from reportdata import matrix, system_facts
from test_report import tables

from runner.report import markdown as report
from runner.report.system import system_rows
from runner.results.document import DmaLatency, IrqThread, MachineInfo, RunDocument

FACT_NAMES = ["Kernel command line", "Clocksource", "CPU topology", "CPU DMA latency", "Interrupts", "Interrupt threads"]


def _facts(**changes: object) -> MachineInfo:
    return system_facts().model_copy(update=changes)


def _with_facts(doc: RunDocument, machine: MachineInfo) -> RunDocument:
    out = copy.deepcopy(doc)
    out.machine = machine
    for cell in out.cells:
        cell.machine = machine
    return out


def test_report_system_rows_sum_up_each_fact_in_one_line():
    rows = dict((name, str(value)) for name, value in system_rows(_facts()))
    assert rows == {
        "Kernel command line": "`quiet isolcpus=2-3 nohz_full=2-3`",
        "Clocksource": "tsc",
        "CPU topology": "SMT siblings 0,2 · 1,3; nohz_full CPUs: 2-3",
        "CPU frequency governor": "performance (CPUs 2-3), powersave (CPUs 0-1)",
        "CPU DMA latency": "held at 0 µs while cells ran (/dev/cpu_dma_latency)",
        "Interrupts": "3 IRQs with a handler; allowed on CPUs 0-3: 2, CPU 1: 1 (smp_affinity_list); "
        "delivered to CPU 0: 1, CPU 1: 2 (effective_affinity_list)",
        "Interrupt threads": "FIFO 50: irq/24-ACPI:Ged (CPU 0), irq/30-eth0 (CPU 1); OTHER: ksoftirqd/0 (CPU 0), ksoftirqd/1 (CPU 1)",
    }


@pytest.mark.parametrize(
    ("dma", "text"),
    [
        (DmaLatency(requested_us=0, held=True, reads_us=None), "held at 0 µs while cells ran (/dev/cpu_dma_latency); not read back"),
        (
            DmaLatency(requested_us=10, held=True, reads_us=0),
            "held at 10 µs while cells ran (/dev/cpu_dma_latency); it read 0 µs, which another program asks for",
        ),
        (
            DmaLatency(requested_us=None, reads_us=2_000_000_000, note="left alone (--no-dma-latency)"),
            "left alone (--no-dma-latency); it read no limit (2,000 s)",
        ),
        (
            DmaLatency(requested_us=0, note="cannot open /dev/cpu_dma_latency: Permission denied; not held"),
            "⚠️ not held at 0 µs: cannot open /dev/cpu_dma_latency: Permission denied; not held",
        ),
    ],
)
def test_report_system_dma_latency_says_what_was_held_or_why_not(dma, text):
    assert dict(system_rows(_facts(dma_latency=dma)))["CPU DMA latency"] == text


def test_report_system_many_interrupt_threads_are_counted_not_listed():
    threads = [IrqThread(pid=10 + n, name=f"ksoftirqd/{n}", policy="other", priority=0, cpus=str(n)) for n in range(64)]
    threads.append(IrqThread(pid=99, name="irq/9-acpi", irq=9, policy="fifo", priority=50, cpus="0-63"))
    row = dict(system_rows(_facts(irq_threads=threads)))["Interrupt threads"]
    assert row == "FIFO 50: irq/9-acpi (CPUs 0-63); OTHER: 64 threads (64 ksoftirqd/…) on CPUs 0-63"


def test_report_system_no_smt_and_no_nohz_full_read_as_such():
    row = dict(system_rows(_facts(smt_siblings=["0", "1"], nohz_full_cpus=None)))["CPU topology"]
    assert row == "no SMT siblings (2 cores, one thread each); nohz_full: not in this kernel"


def test_report_system_facts_an_older_run_did_not_record_get_no_row():
    assert system_rows(MachineInfo(cpus_online="0-1")) == []
    text = report.render_run(matrix())
    assert not any(name in text for name in FACT_NAMES) and "⚠️ **" not in text


def test_report_system_facts_and_warnings_in_the_report():
    """The recorded matrix on a machine with FIFO 50 IRQ threads and isolated CPUs: rows, and a finding per placement."""
    doc = _with_facts(matrix(), _facts(isolated_cpus="2-3"))
    text = report.render_run(doc)
    facts = dict(tables(text)[-1][1:])  # the facts close the report
    assert all(name in facts for name in FACT_NAMES)
    assert facts["CPU frequency governor"] == "performance (CPUs 2-3), powersave (CPUs 0-1)"  # replaces the plain list
    findings = [line for line in text.splitlines() if line.startswith("- ⚠️")]
    label = "**minimal_schedul/minimal_schedul (main)**"
    preempted = [f for f in findings if "interrupt threads of higher RT priority" in f]
    assert [f.split(" at ")[0] for f in preempted] == [
        f"- ⚠️ {label} (cell policy=fifo,priority=10)",
        f"- ⚠️ {label} (cell policy=rr,priority=10)",
    ]
    outside = [f for f in findings if "outside the isolated CPUs 2-3" in f]
    assert len(outside) == 4 and all("is not pinned and may run on CPUs 0-3" in f for f in outside)  # every RT cell, not OTHER
    assert all(cell not in " ".join(outside) for cell in ("policy=other",))


def test_report_system_a_warning_in_every_cell_says_so_once():
    doc = _with_facts(matrix(), _facts(isolated_cpus="2-3"))
    doc.cells = [c for c in doc.cells if "priority=80" in c.id]
    findings = [line for line in report.render_run(doc).splitlines() if line.startswith("- ⚠️")]
    fifo = [f for f in findings if "at FIFO 80" in f]
    assert len(fifo) == 1 and "(cell policy=fifo,priority=80)" in fifo[0]
    doc.cells = [c for c in doc.cells if c.id == "policy=fifo,priority=80"]
    [single] = [line for line in report.render_run(doc).splitlines() if line.startswith("- ⚠️")]
    assert single.startswith("- ⚠️ **minimal_schedul/minimal_schedul (main)** at FIFO 80 is not pinned")  # one cell: no cell named


def test_report_system_a_hostile_cmdline_stays_one_table_cell():
    doc = _with_facts(matrix(), _facts(cmdline="a|b `c` <script> | ## x\\"))
    facts = tables(report.render_run(doc))[-1]
    assert all(len(row) == 2 for row in facts)
    assert dict(facts[1:])["Kernel command line"].count("a|b") == 1
