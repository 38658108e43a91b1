"""The machine's system facts as rows of the report's facts table, and the placement warnings as findings.

Pure, like the rest of the report.  The facts are summed up in a line each (the whole
lists stay in results.json): the kernel command line, the clocksource, CPU topology and
isolation, the DMA latency hold, where interrupts go and how their threads are scheduled.
A fact the run did not record (an older results file) gets no row, rather than a row
that would claim "none".
"""

from __future__ import annotations

from collections.abc import Sequence

from runner import units
from runner.report.fmt import Markdown, md_code, md_text
from runner.report.placement import cpu_set, placement_warnings
from runner.results.document import DMA_LATENCY_NO_LIMIT_US, CellResult, DmaLatency, IrqThread, MachineInfo

MAX_LISTED = 4  # interrupt threads of one scheduling named in the facts; more are summed up


def system_rows(m: MachineInfo) -> list[list[str]]:
    """The facts table's rows for the system facts `m` holds, in reading order; none for what it does not hold."""
    rows: list[list[str]] = []
    if m.cmdline is not None:
        rows.append(["Kernel command line", md_code(m.cmdline, in_table=True) if m.cmdline else "empty"])
    if m.clocksource is not None:
        rows.append(["Clocksource", m.clocksource])
    if m.smt_siblings is not None or m.nohz_full_cpus is not None:
        rows.append(["CPU topology", _topology(m)])
    if m.cpufreq_governor_cpus:
        rows.append(["CPU frequency governor", ", ".join(f"{g} (CPUs {cpus})" for g, cpus in m.cpufreq_governor_cpus.items())])
    if m.dma_latency is not None:
        rows.append(["CPU DMA latency", _dma(m.dma_latency)])
    if m.irqs is not None:
        rows.append(["Interrupts", _irqs(m)])
    if m.irq_threads is not None:
        rows.append(["Interrupt threads", _irq_threads(m.irq_threads)])
    return rows


def _topology(m: MachineInfo) -> str:
    """`SMT siblings 0,2 1,3 (2 threads per core); nohz_full CPUs: 2-3`."""
    parts = []
    if m.smt_siblings is not None:
        groups = m.smt_siblings
        if not groups:
            parts.append("SMT siblings not readable")
        elif all("," not in g and "-" not in g for g in groups):
            parts.append(f"no SMT siblings ({len(groups)} core{'s' if len(groups) != 1 else ''}, one thread each)")
        else:
            parts.append(f"SMT siblings {' · '.join(groups)}")
    if m.nohz_full_cpus is None:
        parts.append("nohz_full: not in this kernel")
    else:
        parts.append(f"nohz_full CPUs: {m.nohz_full_cpus or 'none'}")
    return "; ".join(parts)


def _us(value: int) -> str:
    return "no limit (2,000 s)" if value >= DMA_LATENCY_NO_LIMIT_US else f"{value:,} µs"


def _dma(d: DmaLatency) -> str:
    """`held at 0 µs while cells ran`, `left alone (...); it read no limit`, `⚠️ not held: <why>`."""
    if d.held and d.requested_us is not None:
        text = f"held at {_us(d.requested_us)} while cells ran (/dev/cpu_dma_latency)"
        if d.reads_us is None:
            return text + "; not read back"
        if d.reads_us != d.requested_us:
            return text + f"; it read {_us(d.reads_us)}, which another program asks for"
        return text
    reads = f"; it read {_us(d.reads_us)}" if d.reads_us is not None else ""
    if d.requested_us is None:
        return f"{d.note or 'left alone'}{reads}"
    return Markdown(f"⚠️ not held at {_us(d.requested_us)}: {md_text(d.note, in_table=True)}{md_text(reads, in_table=True)}")


def _counted(counts: dict[str, int]) -> str:
    """`CPU 0: 9, CPU 1: 11`: how many IRQs each CPU list has, in CPU order."""
    ordered = sorted(counts.items(), key=lambda kv: sorted(cpu_set(kv[0])))
    return ", ".join(f"CPU{'s' if len(cpu_set(where)) != 1 else ''} {where}: {n}" for where, n in ordered)


def _irqs(m: MachineInfo) -> str:
    """`20 IRQs with a handler; allowed on CPUs 0-1: 20 (...); delivered to CPU 0: 9, CPU 1: 11 (...)`."""
    irqs = m.irqs or []
    if not irqs:
        return "none found"
    allowed: dict[str, int] = {}
    delivered: dict[str, int] = {}
    for irq in irqs:
        allowed[irq.affinity or "?"] = allowed.get(irq.affinity or "?", 0) + 1
        if irq.effective is not None:
            delivered[irq.effective] = delivered.get(irq.effective, 0) + 1
    text = f"{len(irqs)} IRQ{'s' if len(irqs) != 1 else ''} with a handler; allowed on {_counted(allowed)} (smp_affinity_list)"
    if delivered:
        text += f"; delivered to {_counted(delivered)} (effective_affinity_list)"
    return text


def _irq_threads(threads: list[IrqThread]) -> str:
    """Per scheduling, highest first: `FIFO 50: irq/24-ACPI:Ged (CPU 0), ...; OTHER: ksoftirqd/0 (CPU 0), ...`."""
    if not threads:
        return "none found"
    groups: dict[tuple[int, str], list[IrqThread]] = {}
    for t in threads:
        rt = t.policy in ("fifo", "rr")
        groups.setdefault((t.priority if rt else -1, t.policy), []).append(t)
    parts = []
    for (priority, policy), members in sorted(groups.items(), key=lambda kv: (-kv[0][0], kv[0][1])):
        sched = policy.upper() + (f" {priority}" if priority >= 0 else "")
        if len(members) <= MAX_LISTED:
            listed = ", ".join(f"{t.name} (CPU{'s' if len(cpu_set(t.cpus)) != 1 else ''} {t.cpus})" for t in members)
        else:
            cpus: set[int] = set()
            for t in members:
                cpus.update(cpu_set(t.cpus))
            irq = sum(t.name.startswith("irq/") for t in members)
            kinds = [f"{irq} irq/…"] if irq else []
            kinds += [f"{len(members) - irq} ksoftirqd/…"] if irq < len(members) else []
            listed = f"{len(members)} threads ({', '.join(kinds)}) on CPUs {units.format_cpus(cpus)}"
        parts.append(f"{sched}: {listed}")
    return "; ".join(parts)


def placement_findings(cells: Sequence[CellResult], run_machine: MachineInfo, labels: dict[str, str], matrix: bool) -> list[Markdown]:
    """Each placement warning once, with the cells it holds in when the run has several: `⚠️ **thread** at FIFO 10 ...`.

    A cell is judged on the machine it recorded (a merged run may hold cells of several hosts).
    """
    seen: dict[tuple[str, str], list[str]] = {}
    for cell in cells:
        for warning in placement_warnings(cell.machine or run_machine, cell.threads):
            ids = seen.setdefault((warning.thread, warning.words), [])
            if cell.id not in ids:
                ids.append(cell.id)
    every = list(dict.fromkeys(c.id for c in cells))
    out = []
    for (key, words), ids in seen.items():
        where = "" if not matrix else "every cell" if ids == every else f"cell{'s' if len(ids) != 1 else ''} {', '.join(ids)}"
        out.append(Markdown(f"⚠️ **{md_text(labels.get(key, key))}**" + (f" ({md_text(where)})" if where else "") + f" {md_text(words)}."))
    return out
