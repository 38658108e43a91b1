"""Facts about the machine a cell ran on: what a reader needs to trust or compare its numbers.

Besides the kernel, CPUs and RT throttling, the system facts rteval records: the kernel
command line, the clocksource, isolated and nohz_full CPUs, SMT siblings, the CPU frequency
governor per CPU, where each interrupt is delivered, and how the kernel threads that run
interrupt work (`irq/N-name`, `ksoftirqd/N`) are scheduled.  Everything is read from /proc
and /sys as the kernel reports it, in a few milliseconds; a file that cannot be read gives
None (or an empty list) and never an exception, so gathering facts cannot fail a run.
"""

from __future__ import annotations

import os
import platform
import re
import socket
from typing import Optional

from runner import units
from runner.results.document import Irq, IrqThread, MachineInfo, RtThrottling
from runner.scenario.model import Policy

CPU_SYS = "/sys/devices/system/cpu"
PF_KTHREAD = 0x00200000  # include/linux/sched.h: the task is a kernel thread
_IRQ_THREAD = re.compile(r"irq/(\d+)-")


def _read(path: str) -> str | None:
    try:
        with open(path) as handle:
            return handle.read().strip()
    except (OSError, UnicodeDecodeError):
        return None


def _int(text: str | None) -> int | None:
    try:
        return int(text) if text is not None else None
    except ValueError:
        return None


def _cpus(text: str | None) -> tuple[int, ...]:
    """A CPU list as the kernel writes it (`0-3,8`); () when absent, empty or unreadable."""
    if not text:
        return ()
    try:
        return units.parse_cpus(text)
    except units.UnitError:
        return ()


def machine_info() -> MachineInfo:
    """Kernel, PREEMPT_RT, CPUs, RT throttling, memory, host and the system facts, as the kernel reports them."""
    uname = os.uname()
    runtime = _int(_read("/proc/sys/kernel/sched_rt_runtime_us"))
    period = _int(_read("/proc/sys/kernel/sched_rt_period_us"))
    realtime = _read("/sys/kernel/realtime") == "1" or "PREEMPT_RT" in uname.version
    online_text = _read(f"{CPU_SYS}/online")
    online = _cpus(online_text) or tuple(range(os.cpu_count() or 0))
    governors = governor_cpus(online)
    return MachineInfo(
        hostname=socket.gethostname(),
        kernel=uname.release,
        kernel_version=uname.version,
        preempt_rt=realtime,
        preempt=next((m for m in ("PREEMPT_RT", "PREEMPT_DYNAMIC", "PREEMPT") if m in uname.version), "none"),
        arch=uname.machine,
        cpus_online=online_text or str(os.cpu_count()),
        cpus_allowed=len(os.sched_getaffinity(0)),
        isolated_cpus=_read(f"{CPU_SYS}/isolated") or "",
        rt_throttling=RtThrottling.from_sysctl(runtime, period),
        cpufreq_governors=sorted(governors),
        memory_total_bytes=memory_total(_read("/proc/meminfo")),
        python=platform.python_version(),
        cpu_model=cpu_model(_read("/proc/cpuinfo")),
        cmdline=_read("/proc/cmdline"),
        clocksource=_read("/sys/devices/system/clocksource/clocksource0/current_clocksource"),
        nohz_full_cpus=_nohz_full(),
        smt_siblings=smt_siblings(online),
        cpufreq_governor_cpus=governors,
        irqs=irqs(),
        irq_threads=irq_threads(),
    )


def cpu_model(cpuinfo: Optional[str]) -> Optional[str]:
    """The CPU's model as /proc/cpuinfo names it (`model name` on x86, `Model` or `Hardware` on Arm boards); None when unsaid."""
    found: dict[str, str] = {}
    for line in (cpuinfo or "").splitlines():
        name, sep, rest = line.partition(":")
        if sep and name.strip() in ("model name", "Model", "Hardware", "cpu model") and rest.strip():
            found.setdefault(name.strip(), rest.strip())
    return next((found[key] for key in ("model name", "Model", "cpu model", "Hardware") if key in found), None)


def memory_total(meminfo: Optional[str]) -> Optional[int]:
    """Physical memory in bytes: /proc/meminfo's `MemTotal` (the figure `free` shows), else the page count.

    `MemTotal` is usable RAM (less what the kernel reserved at boot); the sysconf fallback,
    for a /proc without it, counts pages the same way on Linux.  None when neither says.
    """
    for line in (meminfo or "").splitlines():
        name, _, rest = line.partition(":")
        if name == "MemTotal":
            number, _, unit = rest.strip().partition(" ")
            if number.isdigit() and unit in ("kB", ""):
                return int(number) * (1024 if unit else 1)
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError):
        return None


def _nohz_full() -> Optional[str]:
    """The nohz_full CPUs (`` for none); None when the kernel was built without NO_HZ_FULL (no such file).

    The file reads `(null)` on some kernels when the option is built in but no CPU is named.
    """
    text = _read(f"{CPU_SYS}/nohz_full")
    return None if text is None else ("" if text == "(null)" else text)


def smt_siblings(online: tuple[int, ...]) -> list[str]:
    """The online CPUs grouped by core: one `thread_siblings_list` per core (`0,4`), ordered by its first CPU.

    A machine without SMT gives one CPU per group.  A CPU whose topology is not readable is left out.
    """
    groups: dict[tuple[int, ...], str] = {}
    for cpu in online:
        text = _read(f"{CPU_SYS}/cpu{cpu}/topology/thread_siblings_list")
        cpus = _cpus(text)
        if cpus and text is not None:
            groups.setdefault(cpus, units.format_cpus(cpus))
    return [groups[key] for key in sorted(groups)]


def governor_cpus(online: tuple[int, ...]) -> dict[str, str]:
    """Each CPU frequency governor and the online CPUs it governs (`{"performance": "0-3"}`); {} without cpufreq."""
    by_governor: dict[str, list[int]] = {}
    for cpu in online:
        governor = _read(f"{CPU_SYS}/cpu{cpu}/cpufreq/scaling_governor")
        if governor:
            by_governor.setdefault(governor, []).append(cpu)
    return {governor: units.format_cpus(cpus) for governor, cpus in sorted(by_governor.items())}


def irqs() -> list[Irq]:
    """Every interrupt that has a handler, with where it may go and where it goes now, in IRQ order.

    The name is the handler list /proc/interrupts shows, read from /sys/kernel/irq/N/actions,
    where it is one comma-separated field instead of a column that has to be guessed from padding.
    An IRQ without a handler never fires, so it is left out; when the names are not readable at
    all (no /sys/kernel/irq), every IRQ is kept, named None.
    """
    try:
        numbers = sorted(int(entry) for entry in os.listdir("/proc/irq") if entry.isdigit())
    except OSError:
        return []
    out = []
    for irq in numbers:
        name = _read(f"/sys/kernel/irq/{irq}/actions")
        if name == "":
            continue
        out.append(
            Irq(
                irq=irq,
                name=name,
                affinity=_read(f"/proc/irq/{irq}/smp_affinity_list"),
                effective=_read(f"/proc/irq/{irq}/effective_affinity_list"),
            )
        )
    return out


def irq_threads() -> list[IrqThread]:
    """The kernel threads that run interrupt work (`irq/*`, `ksoftirqd/*`): policy, RT priority, allowed CPUs.

    Kernel threads are children of kthreadd (PID 2), so its children list is enough where the kernel
    has one (CONFIG_PROC_CHILDREN); otherwise every process is looked at.  Policy and priority come
    from /proc/PID/stat (as ps reads them), the CPUs from sched_getaffinity; a thread that exits
    while being read is left out.  A user process that calls itself `irq/...` is not a kernel thread
    (PF_KTHREAD) and is left out too.
    """
    children = _read("/proc/2/task/2/children")
    if children:
        pids = [int(p) for p in children.split() if p.isdigit()]
    else:
        try:
            pids = [int(p) for p in os.listdir("/proc") if p.isdigit()]
        except OSError:
            return []
    out = []
    for pid in sorted(pids):
        thread = _irq_thread(pid)
        if thread is not None:
            out.append(thread)
    return out


def _irq_thread(pid: int) -> Optional[IrqThread]:
    stat = _read(f"/proc/{pid}/stat")
    if stat is None or "(" not in stat or ")" not in stat:
        return None
    comm = stat[stat.index("(") + 1 : stat.rindex(")")]
    if not comm.startswith(("irq/", "ksoftirqd/")):
        return None
    fields = stat[stat.rindex(")") + 2 :].split()  # fields[0] is stat field 3: field N is fields[N - 3]
    try:
        flags, rtprio, policy = int(fields[9 - 3]), int(fields[40 - 3]), int(fields[41 - 3])
        cpus = os.sched_getaffinity(pid)
    except (IndexError, ValueError, OSError):
        return None
    if not flags & PF_KTHREAD:
        return None
    match = _IRQ_THREAD.match(comm)
    return IrqThread(
        pid=pid,
        name=comm,
        irq=int(match.group(1)) if match else None,
        policy=_policy_name(policy),
        priority=rtprio,
        cpus=units.format_cpus(cpus),
    )


def _policy_name(number: int) -> str:
    try:
        return Policy.from_kernel(number).value
    except ValueError:
        return f"policy {number}"
