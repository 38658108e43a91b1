"""The real `Backend` (backend.py): this machine's kernel, permissions and processes, a watchdog and a guard.

Made once per run: it starts what every cell uses (the watchdog, the guard, the zygote, the
trace's instances) and ends them beside the run's last writes; each cell's processes are
spawn.py's `run_cell`.
"""

from __future__ import annotations

import threading
from contextlib import AbstractContextManager
from typing import Optional

from runner.results.document import DmaLatency, MachineInfo
from runner.run import _probe, dmalatency, kernel, tracing
from runner.run.backend import CellOptions
from runner.run.guard import Guard
from runner.run.machine import machine_info
from runner.run.preflight import Permissions
from runner.run.preflight import check as preflight_check
from runner.run.rawcell import RawCell
from runner.run.spawn import run_cell
from runner.run.zygote import Zygote
from runner.scenario.limits import WATCHDOG_PRIORITY
from runner.scenario.loader import ResolvedCell
from runner.scenario.model import Scenario
from runner.scenario.plan import Settings


class KernelBackend:
    """The real backend: this machine's kernel, permissions and processes, a watchdog and a guard."""

    def __init__(self) -> None:
        self.watchdog = _probe.Watchdog(WATCHDOG_PRIORITY)  # above every scenario thread: priority 99 needs --allow-priority-99
        self.guard = Guard()
        self.traces = tracing.TraceInstances(guard=self.guard)  # set up once, kept to the end of the run
        self.zygote: Optional[Zygote] = None
        self._preparing: Optional[threading.Thread] = None
        self._winding_down: list[threading.Thread] = []

    def prepare(self, trace: bool) -> None:
        """Start, beside the run's own preparations, what every cell uses: the zygote, the trace's instances."""
        self.zygote = Zygote.start(self.guard)
        if trace:
            seed = [self.zygote.proc.pid] if self.zygote is not None else []
            self._preparing = threading.Thread(target=self.traces.prepare, args=(seed,), name="runner-trace-setup", daemon=True)
            self._preparing.start()

    def start_settings(self) -> Settings:
        return kernel.current_settings()

    def preflight(self, scenarios: list[Scenario], start: Settings, allow_degraded: bool, allow_priority_99: bool) -> Permissions:
        return preflight_check(scenarios, start, allow_degraded, allow_priority_99)

    def machine(self) -> MachineInfo:
        return machine_info()

    def hold_dma_latency(self, request_us: Optional[int]) -> AbstractContextManager[DmaLatency]:
        return dmalatency.hold(request_us)

    def pid_width(self) -> int:
        return kernel.pid_width()

    def run_cell(self, cell: ResolvedCell, folder: str, start: Settings, options: CellOptions) -> RawCell:
        if self._preparing is not None:
            self._preparing.join()
            self._preparing = None
        return run_cell(cell, folder, start, options, self)

    def cells_done(self) -> None:
        """End the zygote and remove the trace's instances beside the run's last writes and report.

        Removing the instances waits for RCU in the kernel (130 ms of a fifo80 run's exit on the
        development VM, and the zygote's end 15 ms): nothing the results or the report need.
        `close()` waits for them, before the guard, which watches the instances until then, goes.
        """
        if self._winding_down:
            return
        for target, name in ((self._end_zygote, "runner-zygote-end"), (self._remove_traces, "runner-trace-remove")):
            thread = threading.Thread(target=target, name=name, daemon=True)
            try:
                thread.start()
            except RuntimeError:  # no thread to be had: close() does it
                continue
            self._winding_down.append(thread)

    def _end_zygote(self) -> None:
        if self.zygote is not None:
            self.zygote.close(self.guard)

    def _remove_traces(self) -> None:
        if self._preparing is not None:  # no cell ran: the instances may still be being made
            self._preparing.join()
        self.traces.close()

    def close(self) -> None:
        for thread in self._winding_down:
            thread.join()
        if self._preparing is not None:
            self._preparing.join()
        self._end_zygote()  # no-ops when cells_done() did them
        self.traces.close()
        self.watchdog.close()
        self.guard.close()
