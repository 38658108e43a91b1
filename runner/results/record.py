"""The base of every stored record: fields typed, an unknown keyword an error in Python, an unknown key in a file dropped."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Final

from pydantic import BaseModel, ConfigDict

if TYPE_CHECKING:
    from typing_extensions import Self  # typing's from Python 3.11

FILE: Final = "runner.results file"
"""The validation context of a file being read (`model_validate_json(..., context=FILE)`): its unknown keys are dropped."""


def _open_schema(schema: dict[str, Any], cls: type) -> None:
    """A record's JSON Schema without the `additionalProperties` its `extra="allow"` writes: the schema says nothing of them."""
    schema.pop("additionalProperties", None)


class Record(BaseModel):
    """A stored record: fields typed; an unknown keyword is an error in Python, an unknown key in a file is dropped.

    A file may hold keys this runner does not know (a newer runner added them, or they are
    derived, like a thread's `key`): reading ignores them.  Code that builds a record with a
    misspelt keyword, at any depth (a nested record given as a dict too), gets a TypeError
    instead of a silently missing field; assigning to one is a ValueError, as pydantic says it.

    All with pydantic's public means: a record keeps the keys it does not know (`extra="allow"`)
    and `model_post_init`, which pydantic calls with the validation context once it has validated
    a record, refuses them unless the record comes from data (`model_validate`, `model_validate_json`:
    their context is FILE unless told), where it drops them.  A record has no `__init__` of its own, so pydantic-core
    validates a file without calling one (a custom `__init__` is called for every nested record,
    with the raw data: the first version checked keywords there and set pydantic's private
    `__pydantic_base_init__` marker on it to stop that).
    """

    model_config = ConfigDict(extra="allow", validate_assignment=True, populate_by_name=True, json_schema_extra=_open_schema)

    def model_post_init(self, context: Any, /) -> None:
        extra = self.model_extra
        if extra:
            if context is not FILE:
                unknown = ", ".join(map(repr, extra))
                raise TypeError(f"{type(self).__name__} has no field {unknown}; fields: {', '.join(type(self).model_fields)}")
            extra.clear()

    @classmethod
    def model_validate(cls, obj: Any, *, context: Any = FILE, **options: Any) -> Self:
        """Data (a dump, a file's) read as a file is: its unknown keys (a dump's derived `key`) are dropped."""
        return super().model_validate(obj, context=context, **options)

    @classmethod
    def model_validate_json(cls, json_data: str | bytes | bytearray, *, context: Any = FILE, **options: Any) -> Self:
        """A file's text: its unknown keys are dropped."""
        return super().model_validate_json(json_data, context=context, **options)

    def __setattr__(self, name: str, value: Any) -> None:
        if name not in type(self).model_fields and not name.startswith("_"):  # extra="allow" would keep it
            raise ValueError(f'"{type(self).__name__}" object has no field "{name}"')
        super().__setattr__(name, value)
