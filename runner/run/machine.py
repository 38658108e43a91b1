"""Facts about the machine a cell ran on: what a reader needs to trust or compare its numbers."""

from __future__ import annotations

import os
import platform
import socket

import psutil

from runner.results.document import MachineInfo, RtThrottling


def _read(path: str) -> str | None:
    try:
        with open(path) as handle:
            return handle.read().strip()
    except OSError:
        return None


def _int(text: str | None) -> int | None:
    try:
        return int(text) if text is not None else None
    except ValueError:
        return None


def machine_info() -> MachineInfo:
    """Kernel, PREEMPT_RT, CPUs, RT throttling, memory and host, as the kernel reports them."""
    uname = os.uname()
    runtime = _int(_read("/proc/sys/kernel/sched_rt_runtime_us"))
    period = _int(_read("/proc/sys/kernel/sched_rt_period_us"))
    realtime = _read("/sys/kernel/realtime") == "1" or "PREEMPT_RT" in uname.version
    governors = sorted(
        {g for cpu in range(os.cpu_count() or 0) if (g := _read(f"/sys/devices/system/cpu/cpu{cpu}/cpufreq/scaling_governor"))}
    )
    return MachineInfo(
        hostname=socket.gethostname(),
        kernel=uname.release,
        kernel_version=uname.version,
        preempt_rt=realtime,
        preempt=next((m for m in ("PREEMPT_RT", "PREEMPT_DYNAMIC", "PREEMPT") if m in uname.version), "none"),
        arch=uname.machine,
        cpus_online=_read("/sys/devices/system/cpu/online") or str(os.cpu_count()),
        cpus_allowed=len(os.sched_getaffinity(0)),
        isolated_cpus=_read("/sys/devices/system/cpu/isolated") or "",
        rt_throttling=RtThrottling.from_sysctl(runtime, period),
        cpufreq_governors=governors,
        memory_total_bytes=psutil.virtual_memory().total,
        python=platform.python_version(),
    )
