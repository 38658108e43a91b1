"""What the session needs from the machine, as a protocol: the real kernel, or a fake in tests.

The session (a run's cell loop, resume, repeats, interrupts, exit codes) talks to the
machine only through a `Backend`: the settings processes inherit, the permission
preflight, the machine's facts, and running one cell's processes into a `RawCell`.
`kernelbackend.KernelBackend` is the real one; tests drive the whole run path with a fake
one, in milliseconds and without RT rights.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Optional, Protocol

from runner.results.document import DmaLatency, MachineInfo
from runner.run.preflight import Permissions
from runner.run.rawcell import RawCell
from runner.run.samples import NO_HOLDERS, Sample
from runner.scenario.loader import ResolvedCell
from runner.scenario.model import Scenario
from runner.scenario.plan import Settings


class Interrupted(Exception):
    """A stop was requested (Ctrl-C or SIGTERM): raised at a safe point, never inside a write."""


def _never() -> bool:
    return False


@dataclass
class CellOptions:
    """How to run one cell: its length, and the session's hooks for progress, --follow and stopping."""

    duration_ns: int
    allow_degraded: bool
    follow: Optional[Callable[[str], None]] = None  # one line per callback, as the ros2-realtime-examples log
    progress: Optional[Callable[[str], None]] = None  # a live status line
    stop_requested: Callable[[], bool] = _never  # Ctrl-C or SIGTERM reached the runner: stop at the next safe point
    samples: Optional[SampleSink] = None  # per-callback samples, streamed while the cell runs; None: not kept
    trace: bool = False  # trace the scheduler for the cell's processes (tracefs), where the kernel allows
    allow_priority_99: bool = False  # --allow-priority-99: a program that raised a thread to 99 is a warning, not an error


class SampleSink(Protocol):
    """Where per-callback samples go while a cell runs (the session's samples file)."""

    def write(
        self, key: str, tid: int, samples: list[Sample], mutexes: Sequence[str] = (), holders: Mapping[int, str] = NO_HOLDERS
    ) -> None:
        """Take these callbacks of one thread, in order; never raises (a write error is kept for the end)."""


class Backend(Protocol):
    """The machine a run happens on."""

    def start_settings(self) -> Settings:
        """The settings the processes the runner starts inherit (the runner's own)."""

    def prepare(self, trace: bool) -> None:
        """Get ready for the cells once the run is allowed to go (processes to fork from, the trace's instances)."""

    def preflight(self, scenarios: list[Scenario], start: Settings, allow_degraded: bool, allow_priority_99: bool) -> Permissions:
        """What this user may do; raises PermissionProblem (exit 3) for a right the cells need and lack."""

    def machine(self) -> MachineInfo:
        """The machine's facts for the results: kernel, CPUs, RT throttling, memory."""

    def hold_dma_latency(self, request_us: Optional[int]) -> AbstractContextManager[DmaLatency]:
        """Hold the CPU latency QoS at `request_us` (None: leave it) while the block runs; never raises for the device."""

    def pid_width(self) -> int:
        """Digits of the largest PID, to lay out thread tables as procps does."""

    def run_cell(self, cell: ResolvedCell, folder: str, start: Settings, options: CellOptions) -> RawCell:
        """Run one cell's processes into `folder`; OSError when its files cannot be created."""

    def cells_done(self) -> None:
        """The run's last cell has ended: start letting go of what only cells use, while the run saves and reports."""

    def close(self) -> None:
        """Release what the backend holds (the watchdog thread, the guard process)."""
