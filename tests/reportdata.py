"""Recorded results used by the report, compare and merge tests (real runs on the development VM)."""

from __future__ import annotations

import copy
import os

from runner.results.document import CellResult, DmaLatency, Irq, IrqThread, MachineInfo, RunDocument, ThreadResult
from runner.results.read import load

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")
MATRIX = os.path.join(DATA, "policy_matrix")  # 5 cells, 1 s each, one hog per CPU
MEMORY = os.path.join(DATA, "memory_lock")  # 3 cells: unlocked, locked, locked + preallocated
TRACED = os.path.join(DATA, "traced")  # tests/data/traced.yaml: FIFO 80 and OTHER on CPU 0 under the trace, 2 expectations failed
PROGRAM = os.path.join(DATA, "own_program")  # scenarios/own_program.yaml: cyclictest as a program (command:), traced


def matrix() -> RunDocument:
    return load(MATRIX)


def memory() -> RunDocument:
    return load(MEMORY)


def traced() -> RunDocument:
    return load(TRACED)


def program() -> RunDocument:
    return load(PROGRAM)


def main_thread(cell: CellResult) -> ThreadResult:
    return next(t for t in cell.threads if t.periodic)


def with_figures(doc: RunDocument, cell_id: str, **changes: object) -> RunDocument:
    """A copy of `doc` where the periodic thread of `cell_id` has some figures changed.

    `latency_p99=` is in ns (the figure's unit), `invol_mean=` switches per callback, `callbacks=` a count.  The
    copies are not validated, so a test may put a value there that no run would produce (NaN).
    """
    out = copy.deepcopy(doc)
    cell = next(c for c in out.cells if c.id == cell_id)
    i = cell.threads.index(main_thread(cell))
    t = cell.threads[i]
    f = t.figures
    if "latency_p99" in changes:
        assert f.latency_ns is not None
        f = f.model_copy(update={"latency_ns": f.latency_ns.model_copy(update={"p99": changes["latency_p99"]})})
    if "invol_mean" in changes:
        f = f.model_copy(update={"involuntary": f.involuntary.model_copy(update={"per_callback_mean": changes["invol_mean"]})})
    for name in ("callbacks", "overruns", "missed_consecutive_max"):
        if name in changes:
            f = f.model_copy(update={name: changes[name]})
    cell.threads[i] = t.model_copy(update={"figures": f})
    return out


def with_latencies(doc: RunDocument, cell_id: str, values: list[int]) -> RunDocument:
    """A copy of `doc` where the periodic thread of `cell_id` answered one release per value, with that wake-up latency (ns).

    Its latency histogram, its latency figures and its callbacks all come from `values`, as the native core would have
    made them, so a comparison judges them on their samples (the recorded runs have 10 callbacks a cell, and no histogram).
    """
    from runner.histogram import from_values
    from runner.results.document import ThreadHistograms
    from runner.run.measure import spread

    out = copy.deepcopy(doc)
    cell = next(c for c in out.cells if c.id == cell_id)
    i = cell.threads.index(main_thread(cell))
    t = cell.threads[i]
    hist = from_values(values)
    mean = sum(values) / len(values)
    m2 = sum((v - mean) ** 2 for v in values)
    f = t.figures.model_copy(
        update={
            "latency_ns": spread(hist, mean, m2, len(values)),
            "callbacks": len(values),
            "releases": len(values) + t.figures.missed_releases,
        }
    )
    cell.threads[i] = t.model_copy(update={"figures": f, "histograms": ThreadHistograms(latency=hist)})
    return out


def latencies(n: int, seed: int, typical: int = 50_000, spread: float = 0.1) -> list[int]:
    """`n` wake-up latencies in ns, log-normal about `typical` (a quiet FIFO thread's shape), from a seeded generator."""
    import random

    draw = random.Random(seed)
    return [round(typical * draw.lognormvariate(0, spread)) for _ in range(n)]


def heavy_tail(values: list[int], share: float = 0.05, factor: int = 3) -> list[int]:
    """`values` with their largest `share` made `factor` times as long: a p99 that grew, the rest as it was."""
    cut = sorted(values)[int(len(values) * (1 - share))]
    return [v * factor if v >= cut else v for v in values]


def renamed(folder: str, names: list[tuple[str, str]], cell_ids: list[str] | None = None) -> RunDocument:
    """The recorded matrix copied to `folder` with each cell's periodic thread renamed to (process, name).

    The samples files are rewritten under the new thread keys, so plots find them; `cell_ids`
    renames the cells too (ids as matrix values would make them).
    """
    import gzip
    import shutil

    shutil.copytree(MATRIX, folder, dirs_exist_ok=True)
    doc = load(folder)
    for n, (cell, (process, name)) in enumerate(zip(doc.cells, names)):
        i = cell.threads.index(main_thread(cell))
        old = cell.threads[i].key
        cell.threads[i] = cell.threads[i].model_copy(update={"process": process, "name": name})
        path = doc.samples_path(cell)
        assert path is not None
        with gzip.open(path, "rt", encoding="utf-8") as handle:
            lines = handle.read().splitlines(keepends=True)
        import csv
        import io

        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        for row in csv.reader(lines):
            writer.writerow([cell.threads[i].key if row[0] == old else row[0]] + row[1:])
        with gzip.open(path, "wt", encoding="utf-8") as handle:
            handle.write(out.getvalue())
        if cell_ids is not None:
            cell.id = cell_ids[n]
    if cell_ids is not None:
        doc.matrix_cells = doc.cell_ids = [c.id for c in doc.cells]
    doc.save(os.path.join(folder, "results.json"))
    return load(folder)


def system_facts() -> MachineInfo:
    """A machine with every system fact recorded: SMT, isolated-ready CPUs, FIFO 50 interrupt threads, the DMA hold."""
    return MachineInfo(
        cpus_online="0-3",
        cmdline="quiet isolcpus=2-3 nohz_full=2-3",
        clocksource="tsc",
        nohz_full_cpus="2-3",
        smt_siblings=["0,2", "1,3"],
        cpufreq_governors=["performance", "powersave"],
        cpufreq_governor_cpus={"performance": "2-3", "powersave": "0-1"},
        dma_latency=DmaLatency(requested_us=0, held=True, reads_us=0),
        irqs=[
            Irq(irq=24, name="ACPI:Ged", affinity="0-3", effective="0"),
            Irq(irq=25, name="ACPI:Ged", affinity="0-3", effective="1"),
            Irq(irq=30, name="eth0", affinity="1", effective="1"),
        ],
        irq_threads=[
            IrqThread(pid=14, name="ksoftirqd/0", policy="other", priority=0, cpus="0"),
            IrqThread(pid=22, name="ksoftirqd/1", policy="other", priority=0, cpus="1"),
            IrqThread(pid=50, name="irq/24-ACPI:Ged", irq=24, policy="fifo", priority=50, cpus="0"),
            IrqThread(pid=51, name="irq/30-eth0", irq=30, policy="fifo", priority=50, cpus="1"),
        ],
    )


def many_threads(folder: str, threads: int = 256, processes: int = 8, callbacks: int = 1000, cells: int = 1) -> RunDocument:
    """A run of `cells` cells of `threads` periodic threads in `processes` processes, `callbacks` each, saved in `folder`.

    Synthetic, never run: the recorded policy_matrix's FIFO cell with its periodic thread copied
    `threads` times, each given a native latency histogram and its rows in samples.csv.gz (a
    1 ms period: wake-up latencies of tens of µs, thread i's worst release i µs later than the
    rest, one involuntary switch every `i + 7` callbacks), so reports and plots see what a
    256-thread cell of 1 s gives them.
    """
    import csv
    import gzip
    import random

    from runner import histogram
    from runner.results.document import ThreadHistograms
    from runner.results.files import cell_dir
    from runner.results.samplesfile import SAMPLE_COLUMNS

    doc = matrix()
    template = doc.cells[0]
    base = main_thread(template)
    rng = random.Random(14)
    os.makedirs(folder, exist_ok=True)
    out_cells = []
    for c in range(cells):
        cell = copy.deepcopy(template)
        cell.id = f"policy=fifo,threads={threads},n={c}"
        cell.thread_table = []
        cell.expectations = []
        cell.samples_file = os.path.join(cell_dir(cell.id, 0, False), "samples.csv.gz")
        rows: list[list[object]] = []
        made = []
        for i in range(threads):
            latencies = [rng.randint(20_000, 80_000) for _ in range(callbacks - 1)] + [100_000 + i * 1_000]
            switches = [1 if n % (i + 7) == 0 else 0 for n in range(callbacks)]
            hist = histogram.from_values(latencies)
            assert hist is not None
            spread = base.figures.latency_ns.model_copy(  # type: ignore[union-attr]
                update={"min": hist.min, "p50": hist.quantile(0.5), "p99": hist.quantile(0.99), "max": hist.max}
            )
            figures = base.figures.model_copy(
                update={
                    "callbacks": callbacks,
                    "releases": callbacks,
                    "latency_ns": spread,
                    "involuntary": base.figures.involuntary.model_copy(
                        update={"total": sum(switches), "per_callback_mean": sum(switches) / callbacks, "per_callback_max": 1}
                    ),
                }
            )
            t = base.model_copy(
                update={
                    "process": "worker",
                    "instance": i % processes,
                    "index": i // processes,
                    "name": "cyclic",
                    "tid": 1000 + i,
                    "figures": figures,
                    "histograms": ThreadHistograms(latency=hist),
                }
            )
            made.append(t)
            for n in range(callbacks):
                rows.append(
                    [
                        t.key,
                        t.tid,
                        n,
                        n * 1_000_000,
                        n * 1_000_000 + latencies[n],
                        0,
                        latencies[n],
                        0,
                        0,
                        switches[n],
                        1,
                        0,
                        0,
                        0,
                        0,
                        0,
                        0,
                        0,
                        0,
                        "",  # chain_ns: outside a chain
                        1_000_000,  # period_ns
                        "",  # lock_waits: it locks no mutex
                    ]
                )
        cell.threads = made
        path = os.path.join(folder, cell.samples_file)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with gzip.open(path, "wt", encoding="utf-8", newline="", compresslevel=1) as handle:
            writer = csv.writer(handle, lineterminator="\n")
            writer.writerow(SAMPLE_COLUMNS)
            writer.writerows(rows)
        out_cells.append(cell)
    doc.cells = out_cells
    doc.matrix_cells = doc.cell_ids = [c.id for c in out_cells]
    doc.save(os.path.join(folder, "results.json"))
    return load(folder)
