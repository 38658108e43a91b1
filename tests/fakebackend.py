"""A fake machine for the run path: the session, the evaluation core and the CLI without processes or RT rights.

`FakeBackend.run_cell` plans the cell's threads as the real shell does and makes up
what the native core would have recorded (callbacks, switches, latencies), so the
session's cell loop, resume, repeats, shuffle, --follow, interrupts, write errors and
exit codes run in milliseconds.  What each cell does is set per cell id with `Act`.
"""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Optional

from runner.results.document import DmaLatency, MachineInfo, thread_key
from runner.run.backend import CellOptions
from runner.run.preflight import Permissions
from runner.run.rawcell import ApplyErrors, BackgroundProcess, RawCell, RawThread, Timeline
from runner.run.samples import Sample, slot_of
from runner.scenario.loader import ResolvedCell
from runner.scenario.model import PeriodicWork, Policy, Scenario
from runner.scenario.plan import Settings, plan_scenario

START = Settings(Policy.OTHER, 0, 0, None)


@dataclass
class Act:
    """What the fake machine does in one cell."""

    nivcsw: int = 0  # involuntary switches in every callback
    latency_ns: int = 50_000
    served: float = 1.0  # fraction of releases a callback served
    failures: tuple[str, ...] = ()  # a worker died, the watchdog fired
    incidents: tuple[str, ...] = ()  # a hog died, a worker was stopped
    signals: int = 0  # SIGINTs the runner receives during the cell
    degrade: bool = False  # RT policies come back as SCHED_OTHER
    oserror: Optional[int] = None  # errno of creating the cell's files
    follow_lines: int = 0  # --follow lines to print
    released_late: tuple[tuple[str, int], ...] = ()  # measured processes whose threads passed their start gate after the common start
    dies: bool = False  # the runner dies here, as under SIGKILL: nothing after this cell's start runs


class Died(BaseException):
    """The fake runner's death: a BaseException that no `except Exception` or OSError handler of the session takes."""


@dataclass
class FakeBackend:
    acts: dict[str, Act] = field(default_factory=dict)
    ran: list[str] = field(default_factory=list)
    closed: bool = False
    cells_over: bool = False  # cells_done() was called
    prepared: Optional[bool] = None  # prepare()'s trace argument, once the session called it
    dma_refused: str = ""  # why the fake /dev/cpu_dma_latency cannot be held; "" holds it
    dma_requests: list[Optional[int]] = field(default_factory=list)
    dma_held_during: list[str] = field(default_factory=list)  # the cells that ran while the fake device was held
    signal_on_prepare: Optional[int] = None  # a signal the runner receives while it prepares (zygote, trace instances)
    signal_on_close: Optional[int] = None  # a signal the runner receives while it cleans up, its report written
    dma_holding: bool = False

    def start_settings(self) -> Settings:
        return START

    def preflight(self, scenarios: list[Scenario], start: Settings, allow_degraded: bool, allow_priority_99: bool) -> Permissions:
        return Permissions("tester", 1000, True, True, 99, -1)

    def machine(self) -> MachineInfo:
        return MachineInfo(kernel="6.0.0-fake", preempt_rt=False, cpus_online="0-1", hostname="fake")

    @contextlib.contextmanager
    def hold_dma_latency(self, request_us: Optional[int]) -> Iterator[DmaLatency]:
        """The device held as the real one is, without touching /dev/cpu_dma_latency."""
        self.dma_requests.append(request_us)
        if request_us is None or self.dma_refused:
            yield DmaLatency(requested_us=request_us, note=self.dma_refused or "left alone (--no-dma-latency)")
            return
        self.dma_holding = True
        try:
            yield DmaLatency(requested_us=request_us, held=True, reads_us=request_us)
        finally:
            self.dma_holding = False

    def pid_width(self) -> int:
        return 5

    def prepare(self, trace: bool) -> None:
        self.prepared = trace
        if self.signal_on_prepare is not None:
            os.kill(os.getpid(), self.signal_on_prepare)

    def run_cell(self, cell: ResolvedCell, folder: str, start: Settings, options: CellOptions) -> RawCell:
        act = self.acts.get(cell.id, Act())
        self.ran.append(cell.id)
        if self.dma_holding:
            self.dma_held_during.append(cell.id)
        if act.dies:
            raise Died(cell.id)
        if act.oserror is not None:
            raise OSError(act.oserror, os.strerror(act.oserror), os.path.join(folder, "p.0.smp"))
        for _ in range(act.signals):
            os.kill(os.getpid(), signal.SIGINT)
        for n in range(act.follow_lines):
            assert options.follow is not None
            options.follow(f"[INFO] [fake] callback {n}")
        interrupted = options.stop_requested()
        scenario = cell.scenario.replace(duration=options.duration_ns)
        t0 = 1_000_000_000
        t_end = t0 + options.duration_ns
        threads = []
        for p in plan_scenario(scenario, start):
            samples: list[Sample] = []
            period = p.work.period if isinstance(p.work, PeriodicWork) else 0
            if isinstance(p.work, PeriodicWork):
                due = options.duration_ns // period
                served = int(due * act.served)
                samples = [
                    Sample(
                        t0 + k * period,
                        t0 + k * period + act.latency_ns,
                        t0 + k * period + act.latency_ns + p.work.burn,
                        p.work.burn,
                        k,
                        act.nivcsw,
                        1,
                        0,
                        0,
                        0,
                        0,
                        0,
                        period_ns=period,
                        next_ns=t0 + (k + 1) * period,
                    )
                    for k in range(served)
                ]
            tid = 10_000 + len(threads)
            slot = slot_of(
                samples,
                tid=tid,
                end_ru=(act.nivcsw * len(samples), len(samples), 0, 0),
                cpus_seen=(0,),
                work_start_ns=t0,
                work_end_ns=t_end,
                bound=scenario.latency_bound or 0,
            )
            if samples and options.samples is not None:
                options.samples.write(thread_key(p.process, p.instance, p.index, p.name), tid, samples)
            applied = Settings(Policy.OTHER, 0, p.settings.nice, p.settings.cpus) if act.degrade else p.settings
            threads.append(RawThread(p, 4242, slot, applied, ApplyErrors(sched=1 if act.degrade else 0), True, len(samples)))
            assert p.periodic or not samples
        timeline = Timeline(0, t0, t_end, t_end + 1_000_000, t_end + 2_000_000)
        return RawCell(
            "2026-11-22T00:00:00+00:00",
            tuple(threads),
            1,
            timeline,
            (),
            act.failures,
            act.incidents,
            interrupted,
            (BackgroundProcess("hog", "hog", 4343),),
            released_late=act.released_late,
        )

    def cells_done(self) -> None:
        self.cells_over = True

    def close(self) -> None:
        self.closed = True
        if self.signal_on_close is not None:
            os.kill(os.getpid(), self.signal_on_close)
