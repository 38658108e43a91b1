"""The ways to write a policy (ours, the kernel's names, rtla's -P) and the messages for what is refused: pure."""

from __future__ import annotations

import re

import pytest

from runner.scenario.model import POLICY_PATTERN, SCHED_PATTERN, Policy, Sched, policy_pattern
from runner.scenario.typed import Invalid


@pytest.mark.parametrize(
    "text, policy, priority, nice",
    [
        ("fifo:80", Policy.FIFO, 80, None),
        ("SCHED_FIFO:80", Policy.FIFO, 80, None),
        ("Sched_RR:40", Policy.RR, 40, None),
        ("normal", Policy.OTHER, None, None),
        ("SCHED_NORMAL:0", Policy.OTHER, 0, None),
        ("f:80", Policy.FIFO, 80, None),  # rtla -P f:80
        ("F:80", Policy.FIFO, 80, None),
        ("r:40", Policy.RR, 40, None),
        ("o:0", Policy.OTHER, None, 0),  # rtla's o:N is SCHED_OTHER at nice N
        ("o:-5", Policy.OTHER, None, -5),
        ("O:19", Policy.OTHER, None, 19),
    ],
)
def test_text_forms(text, policy, priority, nice):
    sched = Sched.parse(text)
    assert (sched.policy, sched.priority, sched.nice) == (policy, priority, nice)
    assert re.fullmatch(SCHED_PATTERN, text)


@pytest.mark.parametrize(
    "text, runtime, deadline, period",
    [
        ("d:2ms:10ms", 2_000_000, 10_000_000, 10_000_000),  # rtla: the deadline is the period
        ("D:100us:1ms", 100_000, 1_000_000, 1_000_000),
        ("d:2000000:10000000", 2_000_000, 10_000_000, 10_000_000),  # rtla reads bare numbers as ns
        ("deadline:2ms/8ms/10ms", 2_000_000, 8_000_000, 10_000_000),
        ("SCHED_DEADLINE:2ms", 2_000_000, 2_000_000, 2_000_000),
    ],
)
def test_deadline_text_forms(text, runtime, deadline, period):
    sched = Sched.parse(text)
    assert (sched.policy, sched.runtime, sched.deadline, sched.period) == (Policy.DEADLINE, runtime, deadline, period)
    assert re.fullmatch(SCHED_PATTERN, text)


@pytest.mark.parametrize("policy", ["SCHED_FIFO", "FIFO", "fifo", "Fifo"])
def test_mapping_policy_words(policy):
    assert Sched.parse({"policy": policy, "priority": 80}).policy is Policy.FIFO
    assert re.fullmatch(POLICY_PATTERN, policy) and re.fullmatch(policy_pattern("fifo"), policy)


@pytest.mark.parametrize(
    "text, message",
    [
        ("other:-5", "priority -5 is not for other, which takes a nice value instead: write {policy: other, nice: -5} (rtla: o:-5)"),
        ("other:80", "an RT priority (80) needs a real-time policy; use fifo:80 or rr:80, or a nice value for other"),
        ("batch:10", "use fifo:10 or rr:10, or for nice 10 write {policy: batch, nice: 10}"),
        ("other:-50", "priority -50 is not for other, which takes a nice value -20..19"),
        ("idle:5", "idle takes neither a priority nor a nice value"),
        ("deadline", "policy deadline needs a runtime: write deadline:RUNTIME[/DEADLINE[/PERIOD]]"),
        ("fifo:0", "priority 0 is out of range for fifo; expected 1..99"),
        ("f:100", "priority 100 is out of range for fifo"),
        ("fifo", "policy fifo needs a priority 1..99"),
        ("o:20", "rtla's o: takes a nice value -20..19"),
        ("f", "rtla's one-letter forms take a value"),
        ("d:1ms", "write d:RUNTIME:PERIOD as rtla does"),
        ("fifoo:80", "'fifoo' is not a policy; did you mean 'fifo'?"),
        ("fifo: 80", "priority ' 80' in 'fifo: 80' is not an integer"),
        ("fifo:" + "9" * 5000, "far out of range"),
    ],
)
def test_refused_text_forms_say_what_to_write(text, message):
    with pytest.raises(Invalid) as caught:
        Sched.parse(text)
    assert message in str(caught.value)
    assert not re.fullmatch(SCHED_PATTERN, text)  # and the schema refuses it too
