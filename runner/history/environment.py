"""The facts of a night's environment a history keeps, and what changed from one night to the next.  Pure.

From the results' machine facts (runner/run/machine.py) and plan: what could explain a change of the
figures that is not the scheduling itself.  A change point is annotated with the facts that changed
that night ("since kernel 6.12.8 -> 6.12.9: p99 +7 us").  Facts a night did not record (an older
runner's file) are left out, never taken as a change.
"""

from __future__ import annotations

from collections.abc import Mapping

from runner.results.document import RunDocument

WORDS = {
    "kernel": "kernel",
    "kernel_version": "kernel build",
    "preempt_rt": "PREEMPT_RT",
    "preempt": "preemption model",
    "cmdline": "kernel command line",
    "cpu_model": "CPU model",
    "cpus_online": "CPUs online",
    "governors": "CPU frequency governors",
    "isolated_cpus": "isolated CPUs",
    "nohz_full": "nohz_full CPUs",
    "clocksource": "clocksource",
    "rt_throttling": "RT throttling",
    "irqs": "IRQ placement",
    "runner": "runner version",
    "scenario_hash": "scenario file",
    "python": "Python",
}


def facts(doc: RunDocument) -> dict[str, str]:
    """The night's environment as text facts, by key of `WORDS`; a fact not recorded is absent."""
    m = doc.machine
    out: dict[str, str] = {
        "kernel": m.kernel or "",
        "kernel_version": m.kernel_version,
        "preempt_rt": "yes" if m.preempt_rt else "no",
        "preempt": m.preempt or "",
        "cmdline": m.cmdline or "",
        "cpu_model": m.cpu_model or "",
        "cpus_online": m.cpus_online or "",
        "governors": ", ".join(f"{g} {cpus}" for g, cpus in (m.cpufreq_governor_cpus or {}).items()) or ", ".join(m.cpufreq_governors),
        "isolated_cpus": m.isolated_cpus,
        "nohz_full": m.nohz_full_cpus or "",
        "clocksource": m.clocksource or "",
        "rt_throttling": _throttling(doc),
        "irqs": "; ".join(f"{i.irq} {i.name or '?'}: {i.effective or i.affinity or '?'}" for i in m.irqs or []),
        "runner": doc.tool.version,
        "scenario_hash": doc.plan.scenario_hash or "",
        "python": m.python or "",
    }
    return {key: value for key, value in out.items() if value}


def _throttling(doc: RunDocument) -> str:
    t = doc.machine.rt_throttling
    if t is None:
        return ""
    if not t.enabled:
        return "off"
    return f"{(t.runtime_ns or 0) // 1000} of {(t.period_ns or 0) // 1000} us"


def changes(before: Mapping[str, str], after: Mapping[str, str]) -> list[str]:
    """What changed between two nights' facts, in words: `kernel 6.12.8 → 6.12.9`; a fact either did not record is skipped."""
    out = []
    for key, words in WORDS.items():
        was, now = before.get(key), after.get(key)
        if was is None or now is None or was == now:
            continue
        if key == "irqs":
            out.append(f"{words}: {_irq_changes(was, now)}")
        elif len(was) + len(now) > 120:
            out.append(f"{words} changed")
        else:
            out.append(f"{words} {was} → {now}")
    return out


def _irq_changes(was: str, now: str) -> str:
    """`24 eth0: 0-1 → 1`: the interrupts whose placement changed, at most three named."""
    old = dict(item.split(": ", 1) for item in was.split("; ") if ": " in item)
    new = dict(item.split(": ", 1) for item in now.split("; ") if ": " in item)
    moved = [
        f"{irq}: {old.get(irq, 'none')} → {new.get(irq, 'none')}" for irq in dict.fromkeys([*old, *new]) if old.get(irq) != new.get(irq)
    ]
    return ", ".join(moved[:3]) + (f" and {len(moved) - 3} more" if len(moved) > 3 else "")
