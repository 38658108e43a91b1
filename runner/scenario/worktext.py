"""A thread's work in words (`periodic 100ms, burn 40ms cpu`): the `work` results store and the listing's column.

Pure, and apart from the `--list` renderer (listing.py), which shows it too, so that what
results say of a thread does not depend on how a listing is laid out.
"""

from __future__ import annotations

from runner import units
from runner.scenario.model import BurnClock, PeriodicWork, PhasesWork, SleepWork, SpinWork, Work


def describe_work(work: Work) -> str:
    """`periodic 100ms, burn 40ms cpu` / `spin` / `sleep` / `phases timer 1ms, run 200us`."""
    if isinstance(work, PeriodicWork):
        text = f"periodic {units.format_duration(work.period)}"
        if work.burn:
            clock = "cpu" if work.burn_clock is BurnClock.THREAD_CPU else "wall"
            text += f", burn {units.format_duration(work.burn)} {clock}"
        if work.alloc:
            text += f", alloc {units.format_size(work.alloc)}"
        if work.offset:
            text += f", offset {units.format_duration(work.offset)}"
        return text
    if isinstance(work, SpinWork):
        return "spin"
    if isinstance(work, PhasesWork):
        names = work.phase_names()
        parts = []
        for name, phase in zip(names, work.phases):
            events = ", ".join(e.label() for e in phase.events)
            loop = f" x{phase.loop}" if phase.loop > 1 else ""
            parts.append(f"{name}{loop}: {events}" if len(work.phases) > 1 else events)
        text = "phases " + "; ".join(parts)
        if work.loop:
            text += f" (x{work.loop})"
        if work.delay:
            text += f", delay {units.format_duration(work.delay)}"
        return text
    assert isinstance(work, SleepWork)
    return "sleep"
