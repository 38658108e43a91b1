"""The machine a run ran on, and what its user was allowed to do, as stored in results (runner.results/2).

Facts, not figures: rteval's system facts, RT throttling, interrupts and their threads, the
DMA latency hold, the user's rights.  Re-exported by runner/results/document.py.
"""

from __future__ import annotations

from typing import Optional

from pydantic import Field, NonNegativeInt

from runner.results.record import Record as _Record


class RtThrottling(_Record):
    """The kernel's RT throttling (sched_rt_runtime_us / sched_rt_period_us), in ns."""

    runtime_ns: Optional[int] = Field(None, description="RT time allowed per period; null: unlimited or not known")
    period_ns: Optional[int] = None
    enabled: bool = False

    @classmethod
    def from_sysctl(cls, runtime_us: Optional[int], period_us: Optional[int]) -> RtThrottling:
        """From the two sysctls as the kernel reports them (runtime -1: no throttling)."""
        enabled = runtime_us is not None and runtime_us >= 0
        return cls(
            runtime_ns=runtime_us * 1000 if enabled and runtime_us is not None else None,
            period_ns=None if period_us is None else period_us * 1000,
            enabled=enabled,
        )


class Irq(_Record):
    """One interrupt line as the kernel routes it (/proc/irq/N, /sys/kernel/irq/N)."""

    irq: NonNegativeInt
    name: Optional[str] = Field(None, description="its handlers, comma-separated, as /proc/interrupts names them; null: not readable")
    affinity: Optional[str] = Field(None, description="CPUs it may be delivered to (smp_affinity_list), e.g. `0-3`")
    effective: Optional[str] = Field(None, description="CPUs it is delivered to now (effective_affinity_list); null: not exposed")


class IrqThread(_Record):
    """A kernel thread that runs interrupt work (`irq/N-name`, `ksoftirqd/N`), scheduled as the kernel holds it."""

    pid: int
    name: str = Field(description="its comm, e.g. `irq/24-ACPI:Ged` (the kernel cuts it at 15 characters)")
    irq: Optional[int] = Field(None, description="the interrupt it serves; null for ksoftirqd")
    policy: str = Field(description="`other`, `fifo`, `rr`, `batch`, `idle`, `deadline`, or `policy N` for another")
    priority: int = Field(description="RT priority (0 unless fifo or rr)")
    cpus: str = Field(description="CPUs it may run on, e.g. `0-3`")


DMA_LATENCY_NO_LIMIT_US = 2_000_000_000  # what /dev/cpu_dma_latency reads when no one asks for less: 2000 s


class DmaLatency(_Record):
    """/dev/cpu_dma_latency (the CPU latency PM QoS) as the run held it: how deep the CPUs could sleep while cells ran."""

    requested_us: Optional[int] = Field(None, description="the latency asked for, in us; null: left alone (--no-dma-latency)")
    held: bool = Field(False, description="the runner held the device open at `requested_us` for the whole cell loop")
    reads_us: Optional[int] = Field(
        None, description="what the device read while held (the lowest any holder asks for), in us; null: not readable"
    )
    note: str = Field("", description="why it was not held, in words")


class MachineInfo(_Record):
    """Facts about the machine a run (or a cell) ran on: what a reader needs to trust or compare its numbers.

    The fields from `cmdline` on (rteval's system facts, and the DMA latency hold) were added within
    runner.results/2: an older file has none of them, and they read as null (not recorded), never as "none".
    """

    hostname: Optional[str] = None
    kernel: Optional[str] = None
    kernel_version: str = ""
    preempt_rt: bool = False
    preempt: Optional[str] = None
    arch: Optional[str] = None
    cpus_online: Optional[str] = None
    cpus_allowed: Optional[int] = None
    isolated_cpus: str = ""
    rt_throttling: Optional[RtThrottling] = None
    cpufreq_governors: list[str] = Field(default_factory=list)
    memory_total_bytes: Optional[int] = None
    python: Optional[str] = None
    cpu_model: Optional[str] = Field(None, description="the CPU's model name (/proc/cpuinfo); null: not recorded or not said")
    cmdline: Optional[str] = Field(None, description="the kernel command line (/proc/cmdline)")
    clocksource: Optional[str] = Field(None, description="the current clocksource, e.g. `tsc`")
    nohz_full_cpus: Optional[str] = Field(None, description="CPUs without a scheduler tick; null: the kernel has no nohz_full")
    smt_siblings: Optional[list[str]] = Field(None, description="hardware threads that share a core, one CPU list per core, e.g. `0,4`")
    cpufreq_governor_cpus: Optional[dict[str, str]] = Field(None, description="each CPU frequency governor and the CPUs it governs")
    irqs: Optional[list[Irq]] = None
    irq_threads: Optional[list[IrqThread]] = None
    dma_latency: Optional[DmaLatency] = None


class PermissionsInfo(_Record):
    """What the user running it was allowed to do."""

    user: Optional[str] = None
    uid: Optional[int] = None
    cap_sys_nice: bool = False
    cap_ipc_lock: bool = False
    rlimit_rtprio: Optional[int] = None
    rlimit_memlock: Optional[int] = Field(None, description="bytes; -1 unlimited")
    missing: list[str] = Field(default_factory=list, description="rights the cells needed and lacked, in words")
