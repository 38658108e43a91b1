"""Where a cell's RT threads ran, against the machine's interrupt threads and isolated CPUs: the report's warnings.

Pure: a cell's machine facts and its measured threads in, warnings out.  Two placements
undo what an RT priority is for, and the report says so in words (as rteval's report does):

- an RT thread (FIFO or RR) that may run on a CPU where an interrupt thread (`irq/N-name`,
  `ksoftirqd/N`) runs at a higher RT priority: whenever that interrupt fires, its thread
  preempts the measured one, which shows as wake-up latency and involuntary switches;
- an RT thread allowed on CPUs outside the isolated ones, when the machine isolates some:
  it shares its CPU with everything the isolation was meant to keep away.

The comparison uses the thread's applied settings (what the kernel held, not what the
scenario asked) and the interrupt threads' scheduling as the run recorded it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from runner import units
from runner.results.document import IrqThread, MachineInfo, ThreadResult

MAX_NAMED = 4  # interrupt threads named in one warning; the rest are counted


@dataclass(frozen=True)
class PlacementWarning:
    """One thread placed where it can be preempted or disturbed: its key, and why in words (without its name)."""

    thread: str
    words: str


def cpu_set(text: str | None) -> frozenset[int]:
    """A CPU list as the kernel writes it (`0-3,8`) as a set; empty when absent or not a CPU list."""
    if not text:
        return frozenset()
    try:
        return frozenset(units.parse_cpus(text))
    except units.UnitError:
        return frozenset()


def _realtime(policy: str) -> bool:
    return policy in ("fifo", "rr")


def placement_warnings(machine: MachineInfo, threads: Sequence[ThreadResult]) -> list[PlacementWarning]:
    """The warnings for a cell's threads on `machine`, in thread order; none for facts the run did not record.

    A thread whose applied CPUs are all (`cpus` None) may run on every online CPU.  Interrupt
    threads at the same priority do not preempt a FIFO thread, so only higher ones count.
    """
    online = cpu_set(machine.cpus_online)
    isolated = cpu_set(machine.isolated_cpus)
    out = []
    for t in threads:
        applied = t.applied
        if applied is None or not applied.policy.is_realtime:
            continue
        where = frozenset(applied.cpus) if applied.cpus is not None else online
        sched = f"{applied.policy.name} {applied.priority}"
        place = f"on CPU{'s' if len(where) != 1 else ''} {units.format_cpus(where)}" if where else "on every CPU"
        above = [
            k
            for k in machine.irq_threads or []
            if _realtime(k.policy) and k.priority > applied.priority and (not where or where & cpu_set(k.cpus))
        ]
        if above:
            out.append(PlacementWarning(t.key, _preempted(sched, place, where, above)))
        outside = where - isolated if where else online - isolated
        if isolated and (outside or not where):
            pinned = "is not pinned and may run" if applied.cpus is None else "is pinned"
            out.append(
                PlacementWarning(
                    t.key,
                    f"at {sched} {pinned} {place}, outside the isolated CPUs {units.format_cpus(isolated)} "
                    f"(CPU{'s' if len(outside) != 1 else ''} {units.format_cpus(outside) or '?'}): it shares them with "
                    "the tasks and interrupts the isolation keeps off the isolated CPUs; pin it to isolated CPUs (`cpus:`)",
                )
            )
    return out


def _preempted(sched: str, place: str, where: frozenset[int], above: list[IrqThread]) -> str:
    """`at FIFO 10 on CPUs 0-1 shares them with 2 interrupt threads of higher priority, ...`."""
    above = sorted(above, key=lambda k: (-k.priority, k.irq if k.irq is not None else -1, k.name))
    named = [f"{k.name} ({k.policy.upper()} {k.priority}, CPU{'s' if len(cpu_set(k.cpus)) != 1 else ''} {k.cpus})" for k in above]
    if len(named) > MAX_NAMED:
        named = named[:MAX_NAMED] + [f"{len(above) - MAX_NAMED} more"]
    count = f"{len(above)} interrupt thread{'s' if len(above) != 1 else ''}"
    return (
        f"at {sched} {place} shares {'them' if len(where) != 1 else 'it'} with {count} of higher RT priority, which "
        f"preempt{'s' if len(above) == 1 else ''} it whenever {'its' if len(above) == 1 else 'their'} interrupt fires: "
        f"{', '.join(named)}; raise its priority above theirs, or move it or the interrupts (smp_affinity_list)"
    )
