"""Scheduling: the policies and `Sched`, written `fifo:80`, as rtla's `f:80`, or as a mapping.

What the kernel is asked for (policy, priority, nice, SCHED_DEADLINE's runtime/deadline/
period), checked against the kernel's own ranges before anything starts.
"""

from __future__ import annotations

import enum
import re
from typing import Any, Optional

from runner import units
from runner.errors import did_you_mean
from runner.scenario.model.base import MAX_PERIOD, MIN_DL_RUNTIME, Duration, Strict
from runner.scenario.typed import Context, Field


class Policy(str, enum.Enum):
    """Linux scheduling policies, by the kernel's numbers (see sched(7))."""

    OTHER = "other"
    FIFO = "fifo"
    RR = "rr"
    BATCH = "batch"
    IDLE = "idle"
    DEADLINE = "deadline"

    @property
    def kernel_id(self) -> int:
        return {"other": 0, "fifo": 1, "rr": 2, "batch": 3, "idle": 5, "deadline": 6}[self.value]

    @property
    def is_realtime(self) -> bool:
        return self in (Policy.FIFO, Policy.RR)

    @classmethod
    def from_kernel(cls, number: int) -> Policy:
        for policy in cls:
            if policy.kernel_id == number:
                return policy
        raise ValueError(f"unknown kernel scheduling policy {number}")


POLICY_WORDS = ["other", "fifo", "rr", "batch", "idle", "deadline"]
_POLICY_ALIASES = {"normal": "other"}  # SCHED_NORMAL is the kernel's name for SCHED_OTHER
_RTLA_LETTERS = {"f": "fifo", "r": "rr", "o": "other", "d": "deadline"}
"""rtla's -P forms (`f:80`, `r:40`, `o:NICE`, `d:RUNTIME:PERIOD`, any case): the letter takes its colon and value."""
SCHED_FORMS = (
    "other, batch, idle, fifo:1..99, rr:1..99, deadline:RUNTIME[/DEADLINE[/PERIOD]] (any case, SCHED_ prefix allowed), "
    "rtla's f:80, r:40, o:NICE, d:RUNTIME:PERIOD, or a mapping {policy: other, nice: -5}"
)
_PRIORITY_DIGITS = 9  # more digits than any priority or nice value: refused before int() (4300 digits would raise)


def _anycase(word: str) -> str:
    """`fifo` -> `[fF][iI][fF][oO]`: case-insensitive without an inline flag, which JavaScript's RegExp refuses."""
    return "".join(f"[{c.lower()}{c.upper()}]" if c.isalpha() else re.escape(c) for c in word)


def _policy_words(*names: str) -> str:
    """A pattern (unanchored) for the policy words `names` in any case, with or without SCHED_."""
    return f"(?:{_anycase('sched_')})?(?:" + "|".join(_anycase(n) for n in names) + ")"


def policy_pattern(*names: str) -> str:
    """The anchored pattern of the policy words `names` as a mapping's `policy:` may write them (SCHED_FIFO, Fifo, normal)."""
    return f"^{_policy_words(*names)}$"


def _sched_patterns() -> tuple[str, str]:
    """The sched text forms and policy words as patterns valid in Python and JavaScript: (written form, policy word).

    The written form is as strict as a pattern can be: fifo and rr with 1..99, other, batch and idle with
    nothing or 0, rtla's o: with a nice value -20..19, deadline with one to three durations.  What needs
    arithmetic (runtime <= deadline <= period, the 1.024us minimum) is left to the model.
    """
    words = _policy_words
    duration = units.DURATION_PATTERN[1:-1]
    rt_priority = "0*[1-9][0-9]?"
    nice = "(?:-?0*1?[0-9]|-0*20)"
    rtla_ns = f"(?:[0-9]+|{duration})"  # rtla reads a bare number as nanoseconds
    written = "|".join(
        (
            f"(?:{words('fifo', 'rr')}|[fFrR]):{rt_priority}",
            f"{words('other', 'normal', 'batch', 'idle')}(?::-?0+)?",
            f"[oO]:{nice}",
            f"{words('deadline')}:{duration}(?:/{duration}){{0,2}}",
            f"[dD]:{rtla_ns}:{rtla_ns}",
        )
    )
    return f"^(?:{written})$", policy_pattern(*POLICY_WORDS, *_POLICY_ALIASES)


SCHED_PATTERN, POLICY_PATTERN = _sched_patterns()


def _policy_name(text: str) -> str:
    word = text.strip().lower()
    if word.startswith("sched_"):
        word = word[len("sched_") :]
    return _POLICY_ALIASES.get(word, word)


def _sched_text(value: str) -> dict[str, Any]:
    """`fifo:80`, `SCHED_RR:40`, `normal`, `f:80`, `o:-5`, `deadline:2ms/8ms/10ms`, `d:2ms:10ms` as the mapping form."""
    match = re.fullmatch(r"([A-Za-z_]+)(?::(.*))?", value, re.DOTALL)
    word = match.group(1).lower() if match else ""
    arg = match.group(2) if match else None
    rtla = word in _RTLA_LETTERS
    policy = _RTLA_LETTERS[word] if rtla else _policy_name(word)
    if rtla and arg is None:
        raise ValueError(f"{value!r}: rtla's one-letter forms take a value: f:80, r:40, o:0 (a nice value), d:2ms:10ms")
    if policy not in POLICY_WORDS:
        shown = word or value
        raise ValueError(f"{shown!r} is not a policy{did_you_mean(shown, POLICY_WORDS)}; expected {SCHED_FORMS}")
    out: dict[str, Any] = {"policy": policy}
    if arg is None:
        return out
    if policy == "deadline":
        parts = arg.split(":" if rtla else "/")
        if rtla:  # rtla's d:RUNTIME:PERIOD, a bare number in ns; the deadline is the period
            if len(parts) != 2:
                raise ValueError(f"{value!r}: write d:RUNTIME:PERIOD as rtla does, e.g. 'd:2ms:10ms'")
            runtime, period = (p + "ns" if p.strip().isdecimal() else p for p in parts)
            return {**out, "runtime": runtime, "deadline": period, "period": period}
        if len(parts) > 3:
            raise ValueError(f"{value!r}: write deadline:RUNTIME/DEADLINE/PERIOD, e.g. 'deadline:2ms/8ms/10ms'")
        out.update(zip(("runtime", "deadline", "period"), parts))
        return out
    number = arg
    if not re.fullmatch(r"-?[0-9]+", number):
        raise ValueError(f"priority {arg!r} in {value!r} is not an integer; write e.g. 'fifo:80'")
    if len(number.lstrip("-0")) > _PRIORITY_DIGITS:
        raise ValueError(f"{number[:12]}… in {value!r} is far out of range; priorities are 1..99, nice values -20..19")
    if rtla and policy == "other":  # rtla's o:N is SCHED_OTHER at nice N
        if not -20 <= int(number) <= 19:
            raise ValueError(f"{value!r}: rtla's o: takes a nice value -20..19, e.g. 'o:-5'")
        return {**out, "nice": int(number)}
    out["priority"] = int(number)
    return out


def _sched_shorthand(value: Any) -> Any:
    """Accept the text forms (see _sched_text) as well as the mapping form, whose policy may be `SCHED_FIFO` or `normal`."""
    if isinstance(value, str):
        return _sched_text(value)
    if isinstance(value, dict) and isinstance(value.get("policy"), str):
        return {**value, "policy": _policy_name(value["policy"])}
    if not isinstance(value, dict):  # `sched: 80`: say what a policy is written as, not only that a mapping is expected
        shown = repr(value) if isinstance(value, (int, float)) else "a list" if isinstance(value, list) else type(value).__name__
        raise ValueError(f"{shown} is not a policy; expected {SCHED_FORMS}")
    return value


def _not_an_rt_policy(policy: Policy, priority: int) -> str:
    """Why `other:80`, `other:-5` or `idle:3` is refused, and what was probably meant (fifo:N, or nice N)."""
    niceable = policy in (Policy.OTHER, Policy.BATCH) and -20 <= priority <= 19
    nice = f"{{policy: {policy.value}, nice: {priority}}}" + (f" (rtla: o:{priority})" if policy is Policy.OTHER else "")
    if 1 <= priority <= 99:
        text = f"an RT priority ({priority}) needs a real-time policy; use fifo:{priority} or rr:{priority}"
        if policy is Policy.IDLE:
            return text + "; idle takes neither a priority nor a nice value"
        return text + (f", or for nice {priority} write {nice}" if niceable else f", or a nice value for {policy.value}")
    if niceable:
        return f"priority {priority} is not for {policy.value}, which takes a nice value instead: write {nice}"
    takes = "a nice value -20..19" if policy in (Policy.OTHER, Policy.BATCH) else "neither a priority nor a nice value"
    return f"priority {priority} is not for {policy.value}, which takes {takes}; RT priorities 1..99 are for fifo and rr"


class Sched(Strict):
    """Scheduling settings: a policy with its RT priority (fifo, rr) or nice value (other, batch)."""

    policy: Policy = Field(description="other, batch, idle, fifo, rr or deadline (SCHED_ prefix and upper case accepted)")
    priority: Optional[int] = Field(default=None, description="RT priority 1..99 for fifo and rr; 0 or absent otherwise")
    nice: Optional[int] = Field(default=None, ge=-20, le=19, description="nice value -20..19 for other and batch")
    runtime: Optional[Duration] = Field(default=None, description="deadline: CPU time granted every period (sched_runtime)")
    deadline: Optional[Duration] = Field(default=None, description="deadline: relative deadline (default: the period, as rt-app)")
    period: Optional[Duration] = Field(default=None, description="deadline: period (default: the runtime, as rt-app)")
    util_min: Optional[int] = Field(default=None, ge=0, le=1024, description="uclamp minimum utilisation 0..1024 (kernels with uclamp)")
    util_max: Optional[int] = Field(default=None, ge=0, le=1024, description="uclamp maximum utilisation 0..1024 (kernels with uclamp)")

    @classmethod
    def _schema(cls, schema: dict[str, Any]) -> None:
        schema["examples"] = ["fifo:80", "SCHED_RR", {"policy": "other", "nice": -5}]

    def _dumped(self, data: dict[str, Any]) -> Any:
        """Leave the deadline and uclamp keys out while unset, so a cell's spec hash reads as before they existed."""
        for key in ("runtime", "deadline", "period", "util_min", "util_max"):
            if getattr(self, key) is None:
                data.pop(key, None)
        return data

    @classmethod
    def _before(cls, value: Any, context: Context) -> Any:
        return _sched_shorthand(value)

    def _after(self, written: Any, context: Context) -> None:
        policy = self.policy
        if self.util_min is not None and self.util_max is not None and self.util_min > self.util_max:
            raise ValueError(f"util_min {self.util_min} is above util_max {self.util_max}")
        if policy is Policy.DEADLINE:
            self._deadline_consistent()
            return
        if self.runtime is not None or self.deadline is not None or self.period is not None:
            raise ValueError(f"runtime, deadline and period are for policy deadline, not {policy.value}")
        if policy.is_realtime:
            if self.priority is None:
                raise ValueError(f"policy {policy.value} needs a priority 1..99, e.g. '{policy.value}:80'")
            if not 1 <= self.priority <= 99:
                raise ValueError(f"priority {self.priority} is out of range for {policy.value}; expected 1..99")
            if self.nice is not None:
                raise ValueError(f"nice does not apply to {policy.value}; nice is for other and batch")
        elif self.priority not in (None, 0):
            raise ValueError(_not_an_rt_policy(policy, self.priority))
        elif policy is Policy.IDLE and self.nice not in (None, 0):
            raise ValueError("policy idle takes no nice value")

    def _deadline_consistent(self) -> None:
        """SCHED_DEADLINE: runtime <= deadline <= period, defaults as rt-app (period = runtime, deadline = period)."""
        if self.runtime is None:
            raise ValueError(
                "policy deadline needs a runtime: write deadline:RUNTIME[/DEADLINE[/PERIOD]] such as 'deadline:2ms/8ms/10ms', "
                "rtla's 'd:2ms:10ms', or {policy: deadline, runtime: 2ms, period: 10ms}"
            )
        if self.priority not in (None, 0) or self.nice not in (None, 0):
            raise ValueError("policy deadline takes runtime, deadline and period, not a priority or nice value")
        period = self.period if self.period is not None else (self.deadline if self.deadline is not None else self.runtime)
        deadline = self.deadline if self.deadline is not None else period
        if self.runtime < MIN_DL_RUNTIME:
            raise ValueError(f"runtime {units.format_duration(self.runtime)} is below the kernel's minimum of 1.024us")
        if not self.runtime <= deadline <= period:
            raise ValueError(
                f"deadline needs runtime <= deadline <= period; got runtime {units.format_duration(self.runtime)}, "
                f"deadline {units.format_duration(deadline)}, period {units.format_duration(period)}"
            )
        if period > MAX_PERIOD:
            raise ValueError(f"period {units.format_duration(period)} is too long; at most {units.format_duration(MAX_PERIOD)}")
        object.__setattr__(self, "period", period)  # frozen: the resolved defaults are set once, while validating
        object.__setattr__(self, "deadline", deadline)

    @property
    def rt_priority(self) -> int:
        return self.priority or 0

    @property
    def bandwidth(self) -> float:
        """A deadline thread's share of one CPU (runtime / period); 0 for other policies."""
        return self.runtime / self.period if self.policy is Policy.DEADLINE and self.runtime and self.period else 0.0

    def label(self) -> str:
        """Compact form: `fifo:80`, `other`, `other nice=-5`, `deadline 2ms/8ms/10ms`."""
        if self.policy is Policy.DEADLINE:
            parts = (self.runtime or 0, self.deadline or 0, self.period or 0)
            return "deadline " + "/".join(units.format_duration(v) for v in parts)
        text = f"{self.policy.value}:{self.priority}" if self.policy.is_realtime else self.policy.value
        if self.nice:
            text += f" nice={self.nice}"
        return text
