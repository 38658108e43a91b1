from __future__ import annotations

import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from runner import figures as fg
from runner import units


@pytest.mark.parametrize(
    "text, ns",
    [
        ("500ms", 500_000_000),
        ("200us", 200_000),
        ("1.5s", 1_500_000_000),
        ("10m", 600_000_000_000),
        ("250 ns", 250),
        ("2h", 7_200_000_000_000),
    ],
)
def test_durations(text, ns):
    assert units.parse_duration(text) == ns


@pytest.mark.parametrize(
    "value, message",
    [(500, "bare number 500 has no unit"), ("5 sec", "did you mean 's'"), ("fast", "cannot read 'fast'"), (None, "got NoneType")],
)
def test_bad_durations(value, message):
    with pytest.raises(units.UnitError, match=message):
        units.parse_duration(value)


@pytest.mark.parametrize("text, nbytes", [("50MiB", 50 << 20), ("200KiB", 200 << 10), ("0B", 0), ("1.5GiB", 3 << 29)])
def test_sizes(text, nbytes):
    assert units.parse_size(text) == nbytes


def test_sizes_refuse_bare_numbers_and_ambiguous_units():
    with pytest.raises(units.UnitError, match="bare number"):
        units.parse_size(50)
    with pytest.raises(units.UnitError, match="did you mean 'MiB'"):
        units.parse_size("50MB")


@pytest.mark.parametrize(
    "value, cpus", [([1, 0, 1], (0, 1)), ("0-1,3", (0, 1, 3)), ("0b1100", (2, 3)), ("0x3", (0, 1)), (2, (2,)), ("1", (1,))]
)
def test_cpus(value, cpus):
    assert units.parse_cpus(value) == cpus


@pytest.mark.parametrize("value", ["0b0", "3-1", [], "a-b", [True], -1])
def test_bad_cpus(value):
    with pytest.raises(units.UnitError):
        units.parse_cpus(value)


def test_round_trips():
    for text in ("100ms", "40ms", "1.5s", "10m", "200us"):
        assert units.format_duration(units.parse_duration(text)) == text
    for text in ("50MiB", "200KiB", "0B", "3GiB"):
        assert units.format_size(units.parse_size(text)) == text
    assert units.format_cpus((0, 1, 2, 5, 7, 8)) == "0-2,5,7-8"


@pytest.mark.parametrize("value", ["0", 0, " 0 ", "0ms"])
def test_zero_needs_no_unit(value):
    assert units.parse_duration(value) == 0


@pytest.mark.parametrize(
    "parse, text",
    [(units.parse_duration, "1" + "0" * 400 + "s"), (units.parse_size, "1" + "0" * 400 + "B"), (units.parse_size, "1" + "0" * 5000 + "B")],
)
def test_overflowing_numbers_are_refused_with_a_message(parse, text):
    with pytest.raises(units.UnitError, match="has more than 24 digits"):
        parse(text)


def test_decimals_are_exact():
    assert units.parse_duration("1.000000001s") == 1_000_000_001
    assert units.parse_size("0.5KiB") == 512
    assert units.parse_duration("12345678901234.567890123s") == 12_345_678_901_234_567_890_123  # 23 digits, no float near it
    assert units.parse_duration("0" * 5000 + "1.5ms") == 1_500_000, "leading zeros are no digits (int() refuses 4,300)"


@pytest.mark.parametrize(
    "text, ns", [("0.5ns", 0), ("1.5ns", 2), ("2.5ns", 2), ("0.0000000015s", 2), ("0.0000000025s", 2), ("0.0000000026s", 3), (".5us", 500)]
)
def test_a_fraction_of_the_smallest_unit_rounds_half_to_even(text, ns):
    """As Python's round() does (the parser's exact arithmetic was Fraction's, whose round() this is)."""
    assert units.parse_duration(text) == ns


@pytest.mark.parametrize(
    "value, message",
    [
        ("0-99999999999", "beyond what Linux supports"),
        ("0x" + "f" * 100_000, "names CPU"),
        ("1" * 5000, "beyond what Linux supports"),
        ("0-8192", "CPU 8192 is beyond"),
    ],
)
def test_huge_cpu_sets_are_refused_without_expanding_them(value, message):
    with pytest.raises(units.UnitError, match=message):
        units.parse_cpus(value)


@pytest.mark.parametrize(
    "value, cpus",
    [
        ("0-7:2", (0, 2, 4, 6)),  # taskset -c's stride
        ("0-7:2/4", (0, 1, 4, 5)),  # the kernel's groups: the first 2 of every 4
        ("100-130:2/25", (100, 101, 125, 126)),  # Documentation/admin-guide/kernel-parameters.rst's example
        ("0, 1", (0, 1)),
        (" 0 ,1 ", (0, 1)),
        ("all", (0, 1, 3)),
        ("ALL", (0, 1, 3)),
    ],
)
def test_cpulist_forms_of_the_kernel_and_taskset(value, cpus):
    assert units.parse_cpus(value, (0, 1, 3)) == cpus


@pytest.mark.parametrize(
    "value, message",
    [("0-7:0", "stride 0"), ("0-7:3/2", "USED <= GROUP"), ("0-7:1/0", "USED <= GROUP"), ("0 1", "cannot read"), ("all,1", "cannot read")],
)
def test_cpulist_forms_that_are_refused(value, message):
    with pytest.raises(units.UnitError, match=message):
        units.parse_cpus(value, (0, 1))


def test_all_needs_the_machines_cpus():
    with pytest.raises(units.UnitError, match="'all' stands for the CPUs the runner may use"):
        units.parse_cpus("all")


@pytest.mark.parametrize("text", ["0", "100ms", " 1.5 s ", ".5us", "10m"])
def test_the_duration_pattern_reads_what_the_parser_reads(text):
    assert re.fullmatch(units.DURATION_PATTERN, text)
    units.parse_duration(text)


@pytest.mark.parametrize("text", ["1.2.3ms", "500", "ms", "1 sec"])
def test_the_duration_pattern_refuses_what_the_parser_refuses(text):
    assert not re.fullmatch(units.DURATION_PATTERN, text)
    with pytest.raises(units.UnitError):
        units.parse_duration(text)


@pytest.mark.parametrize(
    "values, shown",
    [
        ([142_318_000, 176_000], ["142,318", "176"]),  # OTHER's 142 ms beside FIFO's 176 µs: was `142` and `0` ms
        ([142_318_000, 300_000_000], ["142", "300"]),  # nothing small: ms as before
        ([20_000_000_000, 200_000], ["20,000.00", "0.20"]),  # µs would be too long a number: ms, with decimals
        ([5_400, 176_000], ["5", "176"]),  # whole microseconds, as cyclictest prints them
        ([0, 142_000_000], ["0", "142"]),  # a zero is a zero
        ([7_156_000, 117], ["7,156.0", "0.1"]),  # a lock wait of 117 ns beside 7 ms: was `0` µs
        ([150_000, 400], ["150.0", "0.4"]),
    ],
)
def test_a_duration_column_shows_no_value_that_is_not_zero_as_zero(values, shown):
    column = fg.scale(fg.Unit.NS, values)
    assert [column.number(v) for v in values] == shown


@given(st.integers(min_value=-(10**30), max_value=10**30), st.sampled_from(["", " ", "\t", "  "]))
def test_a_whole_number_reads_back_exactly_within_its_range(n, pad):
    low, high = -(10**20), 10**20
    text = f"{pad}{n}{pad}"
    if low <= n <= high:
        assert units.parse_whole(text, low, high) == n
    else:
        with pytest.raises(units.UnitError, match="is out of range; expected -100,000,000,000,000,000,000 to"):
            units.parse_whole(text, low, high)


@pytest.mark.parametrize("text", ["٣", "²", "３", "1_000", "1e3", "0x10", "", "-", "+-1", "1 2", "9" * 5_000 + "x"])
def test_a_whole_number_is_ascii_digits_only(text):
    """int() reads Arabic-Indic and fullwidth digits and `1_000`; a number a user types here is 0-9."""
    with pytest.raises(units.UnitError, match="is not a whole number"):
        units.parse_whole(text, 0, 10**6)


def test_a_pid_is_ascii_digits_in_pid_ts_range_and_anything_else_is_a_name():
    assert units.parse_pid("1") == 1 and units.parse_pid("2147483647") == 2**31 - 1
    assert units.parse_pid("١") is None and units.parse_pid("sshd") is None and units.parse_pid("-1") is None
    for far in ("2147483648", "9" * 5_000):
        with pytest.raises(units.UnitError, match=r"PID .* is out of range; expected 0 to 2,147,483,647"):
            units.parse_pid(far)
