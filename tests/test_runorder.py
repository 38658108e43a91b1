"""Which cells a run does: shards partition the matrix, repeats and shuffles are deterministic."""

from __future__ import annotations

import pytest

from runner.errors import UsageError
from runner.runorder import Shard, Unit, plan_units


@pytest.mark.parametrize("count", range(1, 8))
@pytest.mark.parametrize("cells", [1, 5, 12, 40])
def test_shards_cover_every_cell_exactly_once(count, cells):
    ids = [f"c{i}" for i in range(cells)]
    parts = [Shard(k, count).take(ids) for k in range(1, count + 1)]
    flat = [c for part in parts for c in part]
    assert sorted(flat) == sorted(ids) and len(flat) == len(set(flat))
    assert max(map(len, parts)) - min(map(len, parts)) <= 1  # balanced


def test_shards_keep_the_matrix_order():
    assert Shard(2, 3).take(list("abcdefg")) == ["b", "e"]


@pytest.mark.parametrize("text", ["0/2", "3/2", "1/0", "a/b", "1", "1/2/3"])
def test_bad_shards_are_usage_errors(text):
    with pytest.raises(UsageError, match="--shard"):
        Shard.parse(text)


def test_repeats_run_round_by_round():
    assert plan_units(["a", "b"], repeat=2) == [Unit("a", 0), Unit("b", 0), Unit("a", 1), Unit("b", 1)]


def test_shuffle_is_repeatable_from_its_seed_and_changes_the_order():
    ids = [f"c{i}" for i in range(10)]
    one, two = plan_units(ids, 2, shuffle_seed=7), plan_units(ids, 2, shuffle_seed=7)
    assert one == two and sorted(one, key=lambda u: (u.repeat, u.cell)) == sorted(plan_units(ids, 2), key=lambda u: (u.repeat, u.cell))
    assert one != plan_units(ids, 2)


def test_finished_units_are_left_out_keeping_the_order():
    ids = ["a", "b", "c"]
    assert plan_units(ids, 1, shuffle_seed=3, done=[("b", 0)]) == [u for u in plan_units(ids, 1, shuffle_seed=3) if u.cell != "b"]
