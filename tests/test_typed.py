"""The typed models' engine (runner.scenario.typed), on small models of its own: records, checks, dumps, schema.

The scenario's own models are tested through the loader (test_scenarios, the invalid corpus, the
fuzzing); these pin what every model gets from the engine, one rule at a time.
"""

from __future__ import annotations

import enum
import typing as t  # for a ClassVar written t.ClassVar
from typing import Annotated, Any, ClassVar, Literal, Optional, Union

import pytest

from runner.scenario.typed import Field, FrozenError, Invalid, Issue, KeyProblem, Model, Schema, Tagged, Written, json_schema, parse


class Colour(str, enum.Enum):
    """A colour."""

    RED = "red"
    GREEN = "green"


def _cents(value: Any, context: Any) -> Any:
    """`1.50$` as 150; anything else is left for the type to judge."""
    if isinstance(value, str) and value.endswith("$"):
        try:
            return round(float(value[:-1]) * 100)
        except ValueError:
            raise ValueError(f"cannot read {value!r}; expected an amount such as 1.50$") from None
    return value


Cents = Annotated[int, Written(_cents, lambda cents: f"{cents / 100:.2f}$", {"type": "string", "pattern": r"^[0-9.]+\$$"})]


class Leaf(Model):
    """A leaf."""

    name: str = Field(description="its name")
    size: int = Field(default=1, ge=1, le=10, description="how big")
    colour: Colour = Field(default=Colour.RED)
    price: Optional[Cents] = Field(default=None)
    tags: list[str] = Field(default_factory=list)
    seen: ClassVar[int] = 0  # a class attribute, not a field


class Tree(Model):
    """A tree: leaves with rules across them."""

    leaves: list[Leaf] = Field(min_items=1)
    spare: Optional[Leaf] = None
    kind: Literal["tree"] = "tree"

    def _after(self, written: Any, context: Any) -> None:
        names = [leaf.name for leaf in self.leaves]
        for i, name in enumerate(names):
            if names.index(name) != i:
                raise KeyProblem(("leaves", i, "name"), f"leaf name {name!r} is used twice")


class Short(Model):
    """Written as text (`word`) or as a mapping; dumped as its word."""

    word: str
    count: int = 0

    @classmethod
    def _before(cls, value: Any, context: Any) -> Any:
        if isinstance(value, str):
            if not value:
                raise ValueError("an empty word")
            return {"word": value}
        return value

    def _dumped(self, data: dict[str, Any]) -> Any:
        return self.word if not self.count else data


class Bush(Model):
    kind: Literal["bush"] = "bush"
    height: int = 1


def _leaf_or_short(value: Any) -> type:
    return Short if isinstance(value, str) else Leaf


class Garden(Model):
    plant: Annotated[Union[Tree, Bush], Tagged(key="kind")]
    choice: Annotated[Union[Leaf, Short], Tagged(choose=_leaf_or_short)] = Field(default_factory=lambda: Short(word="x"))
    extra: dict[str, Union[str, int, float, bool, Annotated[list[Union[str, int, float, bool]], Schema({"minItems": 1})]]] = Field(
        default_factory=dict
    )


class Contextual(Model):
    n: int = 0

    def _after(self, written: Any, context: Any) -> None:
        if context is not None and self.n > context["most"]:
            raise ValueError(f"n {self.n} is above {context['most']}")


def issues(tp: Any, data: Any, context: Any = None) -> list[tuple[tuple[Any, ...], str]]:
    with pytest.raises(Invalid) as caught:
        parse(tp, data, context)
    return sorted((issue.path, issue.message) for issue in caught.value.issues)


# ----------------------------------------------------------------- records


def test_a_model_is_a_frozen_record_made_by_keyword():
    leaf = Leaf(name="a")
    assert (leaf.name, leaf.size, leaf.colour, leaf.price, leaf.tags) == ("a", 1, Colour.RED, None, [])
    assert Leaf(name="a").tags is not leaf.tags, "a factory makes each default anew"
    with pytest.raises(FrozenError):
        leaf.size = 2  # type: ignore[misc]
    with pytest.raises(FrozenError):
        del leaf.name  # type: ignore[misc]
    with pytest.raises(TypeError, match="needs the keyword argument 'name'"):
        Leaf()  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="has no field 'nme'"):
        Leaf(name="a", nme="b")  # type: ignore[call-arg]
    assert "seen" not in [slot.name for slot in Leaf._slots]


def test_models_compare_and_hash_by_type_and_fields():
    assert Short(word="a") == Short(word="a") != Short(word="b")
    assert hash(Short(word="a")) == hash(Short(word="a"))
    assert Bush(height=1) != Short(word="1")
    assert repr(Short(word="a", count=2)) == "Short(word='a', count=2)"


def test_replace_copies_with_changes_and_checks_nothing_again():
    leaf = Leaf(name="a", size=3)
    other = leaf.replace(size=99)
    assert (leaf.size, other.size, other.name) == (3, 99, "a")


# ----------------------------------------------------------------- checking


def test_scalars_are_strict():
    assert issues(Leaf, {"name": 5, "size": "2"}) == [
        (("name",), "input should be a valid string, got 5"),
        (("size",), "input should be a valid integer, got '2'"),
    ]
    assert issues(Leaf, {"name": "a", "size": True}) == [(("size",), "input should be a valid integer, got True")]
    assert issues(Leaf, {"name": "a", "size": 2.0}) == [(("size",), "input should be a valid integer, got 2.0")]
    assert issues(Contextual, {"n": None}) == [(("n",), "input should be a valid integer")]


def test_a_yaml_boolean_where_text_belongs_says_how_to_quote_it():
    ((_, message),) = issues(Leaf, {"name": False})
    assert message.startswith("input should be a valid string, got False; YAML reads an unquoted yes, no, on, off")


def test_bounds_and_lengths():
    assert issues(Leaf, {"name": "a", "size": 0}) == [(("size",), "input should be greater than or equal to 1, got 0")]
    assert issues(Leaf, {"name": "a", "size": 11}) == [(("size",), "input should be less than or equal to 10, got 11")]
    from runner.scenario.model import Phase

    too_many = issues(Phase, {"loop": 2**41, "events": ["yield"]})
    assert too_many == [(("loop",), "input should be less than or equal to 1099511627776, got 2199023255552")], "a bound as written"
    assert issues(Tree, {"leaves": []}) == [(("leaves",), "list should have at least 1 item, not 0")]
    assert issues(Tree, {"leaves": "a"}) == [(("leaves",), "input should be a valid list, got 'a'")]


def test_enums_and_literals_name_what_they_take():
    assert issues(Leaf, {"name": "a", "colour": "gren"}) == [
        (("colour",), "'gren' is not valid; did you mean 'green'?; expected one of: red, green")
    ]
    assert parse(Leaf, {"name": "a", "colour": "green"}).colour is Colour.GREEN
    assert issues(Tree, {"leaves": [{"name": "a"}], "kind": "bush"}) == [(("kind",), "input should be 'tree', got 'bush'")]


def test_every_problem_at_once_each_at_its_path():
    data = {"leaves": [{"name": "a", "size": 0}, {"size": 2}, "x"], "spare": {"name": "b", "price": "x$"}}
    assert issues(Tree, data) == [
        (("leaves", 0, "size"), "input should be greater than or equal to 1, got 0"),
        (("leaves", 1, "name"), "missing required key 'name'"),
        (("leaves", 2), "input should be a mapping (key: value), got 'x'"),
        (("spare", "price"), "cannot read 'x$'; expected an amount such as 1.50$"),
    ]


def test_an_unknown_key_names_what_was_meant_or_every_key():
    assert issues(Leaf, {"name": "a", "sise": 2}) == [(("sise",), "unknown key 'sise'; did you mean 'size'?")]
    assert issues(Leaf, {"name": "a", "zzz": 2}) == [(("zzz",), "unknown key 'zzz'; expected one of: name, size, colour, price, tags")]
    assert issues(Leaf, {"name": "a", 7: 2}) == [((7,), "unknown key 7; expected one of: name, size, colour, price, tags")]


def test_a_typo_of_a_required_key_is_one_problem_not_two():
    assert issues(Leaf, {"nmae": "a"}) == [(("nmae",), "unknown key 'nmae'; did you mean 'name'?")]
    assert issues(Leaf, {"size": 2}) == [(("name",), "missing required key 'name'")]


def test_rules_across_fields_run_once_the_fields_are_valid_and_point_at_their_key():
    two = {"leaves": [{"name": "a"}, {"name": "a"}]}
    assert issues(Tree, two) == [(("leaves", 1, "name"), "leaf name 'a' is used twice")]
    assert issues(Tree, {"leaves": [{"name": "a"}, {"name": "a", "size": 0}]}) == [
        (("leaves", 1, "size"), "input should be greater than or equal to 1, got 0")
    ], "a rule waits for its fields"


def test_a_key_problem_points_only_as_far_as_the_data_goes():
    class Strict(Model):
        items: list[int] = Field(default_factory=list)

        def _after(self, written: Any, context: Any) -> None:
            raise KeyProblem(("items", 5, "deep"), "no")

    Strict.__module__ = __name__
    globals()["Strict"] = Strict
    assert issues(Strict, {"items": [1]}) == [(("items",), "no")]


def test_a_written_form_is_read_before_the_type_and_dumped_after_it():
    leaf = parse(Leaf, {"name": "a", "price": "1.50$"})
    assert leaf.price == 150
    assert leaf.dump()["price"] == "1.50$"
    assert issues(Leaf, {"name": "a", "price": "1.50"}) == [(("price",), "input should be a valid integer, got '1.50'")]


def test_a_shorthand_is_read_into_the_mapping_form_and_its_refusal_is_at_the_value():
    assert parse(Short, "hi") == Short(word="hi")
    assert issues(Short, "") == [((), "an empty word")]
    assert parse(Short, {"word": "hi", "count": 2}).count == 2


def test_a_union_by_tag_says_the_tags_it_takes():
    garden = parse(Garden, {"plant": {"kind": "bush", "height": 3}})
    assert garden.plant == Bush(height=3)
    assert issues(Garden, {"plant": {"height": 3}}) == [(("plant",), "missing 'kind'; expected one of: tree, bush")]
    assert issues(Garden, {"plant": {"kind": "bsh"}}) == [
        (("plant", "kind"), "unknown kind 'bsh'; did you mean 'bush'?; expected one of: tree, bush")
    ]
    assert issues(Garden, {"plant": 3}) == [(("plant",), "input should be a mapping with a 'kind' key (one of: tree, bush), got 3")]


def test_a_union_by_choice_checks_the_chosen_member():
    assert parse(Garden, {"plant": {"kind": "bush"}, "choice": "w"}).choice == Short(word="w")
    assert parse(Garden, {"plant": {"kind": "bush"}, "choice": {"name": "n"}}).choice == Leaf(name="n")
    assert issues(Garden, {"plant": {"kind": "bush"}, "choice": {"word": "n"}}) == [
        (("choice", "name"), "missing required key 'name'"),
        (("choice", "word"), "unknown key 'word'; expected one of: name, size, colour, price, tags"),
    ]


def test_a_union_of_plain_values_keeps_each_as_written():
    extra = {"a": "x", "b": 1, "c": 1.5, "d": True, "e": [1, "y"]}
    assert parse(Garden, {"plant": {"kind": "bush"}, "extra": extra}).extra == extra
    assert issues(Garden, {"plant": {"kind": "bush"}, "extra": {"a": {"b": 1}}}) == [
        (("extra", "a"), "input should be text, a number, a boolean or a list of them")
    ]


def test_the_context_reaches_the_rules():
    assert parse(Contextual, {"n": 5}).n == 5
    assert issues(Contextual, {"n": 5}, {"most": 3}) == [((), "n 5 is above 3")]


# ---------------------------------------------------------------- dumping


def test_a_dump_is_json_data_in_the_written_forms():
    tree = parse(Tree, {"leaves": [{"name": "a", "colour": "green", "price": "2$", "tags": ["t"]}]})
    assert tree.dump() == {
        "leaves": [{"name": "a", "size": 1, "colour": "green", "price": "2.00$", "tags": ["t"]}],
        "spare": None,
        "kind": "tree",
    }
    assert tree.dump(exclude=frozenset({"spare", "kind"})) == {"leaves": [tree.leaves[0].dump()]}
    assert parse(Garden, {"plant": {"kind": "bush"}, "choice": "w"}).dump()["choice"] == "w", "a model's own written form"


# ----------------------------------------------------------------- schema


def test_the_schema_follows_the_declarations():
    schema = json_schema(Tree)
    assert schema["required"] == ["leaves"] and schema["additionalProperties"] is False
    assert schema["description"] == "A tree: leaves with rules across them."
    assert schema["properties"]["leaves"] == {"items": {"$ref": "#/$defs/Leaf"}, "minItems": 1, "title": "Leaves", "type": "array"}
    leaf = schema["$defs"]["Leaf"]["properties"]
    assert leaf["size"] == {"default": 1, "description": "how big", "maximum": 10, "minimum": 1, "title": "Size", "type": "integer"}
    assert leaf["colour"] == {"$ref": "#/$defs/Colour", "default": "red"}
    assert leaf["price"]["anyOf"] == [{"type": "string", "pattern": r"^[0-9.]+\$$"}, {"type": "null"}]
    assert schema["$defs"]["Colour"] == {"description": "A colour.", "enum": ["red", "green"], "title": "Colour", "type": "string"}
    assert schema["properties"]["kind"] == {"const": "tree", "default": "tree", "title": "Kind", "type": "string"}


def test_the_schema_keeps_only_the_definitions_it_refers_to():
    class Replaced(Model):
        colour: Colour = Colour.RED

        @classmethod
        def _schema(cls, schema: dict[str, Any]) -> None:
            schema.clear()
            schema.update({"enum": ["x"]})

    class Holder(Model):
        replaced: Replaced = Field(default_factory=Replaced)

    Replaced.__module__ = Holder.__module__ = __name__
    globals().update(Replaced=Replaced, Holder=Holder)
    assert set(json_schema(Holder)["$defs"]) == {"Replaced"}, "Colour is referred to by nothing left"


def test_a_union_schema_lists_its_members():
    props = json_schema(Garden)["properties"]
    assert props["plant"]["oneOf"] == [{"$ref": "#/$defs/Tree"}, {"$ref": "#/$defs/Bush"}]
    extra = props["extra"]["additionalProperties"]["anyOf"]
    assert extra[-1] == {
        "items": {"anyOf": [{"type": "string"}, {"type": "integer"}, {"type": "number"}, {"type": "boolean"}]},
        "minItems": 1,
        "type": "array",
    }


def test_a_type_the_engine_cannot_check_is_refused_when_first_used():
    class Odd(Model):
        when: complex = 0j

    Odd.__module__ = __name__
    globals()["Odd"] = Odd
    with pytest.raises(TypeError, match="cannot check"):
        parse(Odd, {})


def test_a_number_too_large_for_a_float_is_said_in_digits():
    from runner.scenario.model import Expectation

    assert issues(Expectation, {"thread": "t", "metric": "callbacks", "max": 10**400}) == [
        (("max",), "input should be a valid number; got an integer of about 401 digits")
    ]


def test_a_mapping_of_models_wants_a_mapping_and_models_given_as_models_pass():
    assert issues(Garden, {"plant": {"kind": "bush"}, "extra": "x"}) == [(("extra",), "input should be a mapping (key: value), got 'x'")]
    bush = Bush(height=2)
    assert parse(Garden, {"plant": bush}).plant is bush, "a model already made is taken as it is"
    assert parse(Tree, {"leaves": [Leaf(name="a")]}).leaves == [Leaf(name="a")]


def test_a_literal_takes_its_value_of_its_own_type_only():
    assert parse(Literal[True], True) is True
    assert issues(Literal[1], 1.0) == [((), "input should be 1, got 1.0")]
    assert issues(Literal[1], True) == [((), "input should be 1, got True")]


def test_not_a_number_meets_no_bound():
    class Bounded(Model):
        y: Optional[float] = Field(default=None, ge=0, le=10)

    Bounded.__module__ = __name__
    globals()["Bounded"] = Bounded
    assert issues(Bounded, {"y": float("nan")}) == [(("y",), "input should be greater than or equal to 0, got nan")]


def test_what_a_hook_sets_is_kept_by_replace_and_compared():
    from runner.scenario.model import ThreadSpec

    spec = ThreadSpec.parse({"name": "c", "count": "cpus", "pin": "each"}, {"cpus": [0, 1, 2, 3]})
    copy = spec.replace(inherit=False)
    assert (copy.per_cpu, copy.machine_cpus, copy.inherit) == (True, (0, 1, 2, 3), False)
    written = ThreadSpec(name="c", count=4, cpus=(0, 1, 2, 3), pin=spec.pin)
    assert spec != written, "count: cpus resolved to 4 is not a count of 4 written"
    assert hash(spec) == hash(written)


def test_only_public_annotated_names_are_fields():
    class Base(Model):
        size: int = 1
        _note: int = 0  # a hook's state
        limit: t.ClassVar[int] = 3

    class Child(Base):
        size = 9  # a new default for the inherited field

    for cls in (Base, Child):
        cls.__module__ = __name__
        globals()[cls.__name__] = cls
    assert [slot.name for slot in Base._slots] == ["size"]
    assert issues(Base, {"_note": 1}) == [(("_note",), "unknown key '_note'; expected one of: size")]
    assert (Base().size, Child().size, parse(Child, {}).size) == (1, 9, 9)


def test_unions_equal_to_typing_keep_their_own_order():
    assert issues(Union[int, str], 1.5) == [((), "input should be a number or text, got 1.5")]
    assert issues(Union[str, int], 1.5) == [((), "input should be text or a number, got 1.5")]


def test_an_item_of_a_list_a_union_takes_is_judged_at_its_place():
    assert issues(Garden, {"plant": {"kind": "bush"}, "extra": {"a": [1, [2], {"b": 3}]}}) == [
        (("extra", "a", 1), "input should be text, a number or a boolean"),
        (("extra", "a", 2), "input should be text, a number or a boolean"),
    ]


def test_a_key_that_is_not_text_is_said_at_the_key():
    with pytest.raises(Invalid) as caught:
        parse(Garden, {"plant": {"kind": "bush"}, "extra": {1: "x"}})
    assert caught.value.issues == [Issue(("extra", 1), "the key 1 should be text", key=True)]
