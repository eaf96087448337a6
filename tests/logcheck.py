"""Strict checks of logs against their own channels' schemas (CONTRACTS.md section 2): every
message validates against the schema recorded with its channel, and every field it carries is
declared there. Also the rules Foxglove's JSON-schema parser sets for a channel to be usable.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

from jsonschema import validators
from mcap.reader import make_reader


def strict(schema: object) -> object:
    """`schema` with `"additionalProperties": false` on every object that lists properties
    and says nothing of other keys: an undeclared field then fails validation."""
    if isinstance(schema, dict):
        out = {k: strict(v) for k, v in schema.items()}
        if out.get("type") == "object" and "additionalProperties" not in out:
            out["additionalProperties"] = False
        return out
    if isinstance(schema, list):
        return [strict(v) for v in schema]
    return schema


def validator(schema: dict):
    """A validator of the schema's declared draft (`$schema`), strict about fields."""
    cls = validators.validator_for(schema)
    cls.check_schema(schema)
    return cls(strict(schema))


def problems(topic: str, schema: dict, message: object) -> list[str]:
    return [f"{topic}: /{'/'.join(map(str, e.absolute_path))}: {e.message}"
            for e in validator(schema).iter_errors(message)]


def check_files(paths: Iterable[Path]) -> tuple[Counter, list[str]]:
    """Messages per topic, and every problem (at most a few per topic and kind) of the
    finished files `paths`."""
    counts: Counter = Counter()
    found: list[str] = []
    seen: Counter = Counter()
    cache: dict[tuple[Path, int], object] = {}
    for path in paths:
        with open(path, "rb") as fh:
            for schema, channel, message in make_reader(fh).iter_messages():
                counts[channel.topic] += 1
                if schema is None or schema.encoding != "jsonschema":
                    found.append(f"{channel.topic}: no jsonschema schema")
                    continue
                key = (path, schema.id)
                if key not in cache:
                    cache[key] = validator(json.loads(schema.data))
                for e in cache[key].iter_errors(json.loads(message.data)):
                    text = f"{channel.topic}: /{'/'.join(map(str, e.absolute_path))}: " \
                           f"{e.message[:160]}"
                    seen[text] += 1
                    if seen[text] == 1:
                        found.append(text)
    return counts, found


def foxglove_problems(schema: dict, where: str = "") -> list[str]:
    """What Foxglove's JSON-schema parser would refuse (it then drops the whole channel):
    an object without `"type": "object"` and properties, a field whose type is not one
    string of boolean/string/number/integer/object/array, `$ref`, an array without a typed
    `items`, a `oneOf` that is not an enum of numeric constants."""
    out: list[str] = []
    if schema.get("type") != "object" or not isinstance(schema.get("properties"), dict):
        return [f"{where or '/'}: not an object with properties"]
    for name, field in schema["properties"].items():
        at = f"{where}/{name}"
        if "$ref" in json.dumps(field):
            out.append(f"{at}: $ref")
        if "oneOf" in field:
            if not all(isinstance(a.get("const"), int) for a in field["oneOf"]):
                out.append(f"{at}: oneOf that is not numeric constants")
            continue
        kind = field.get("type")
        if kind == "object":
            out += foxglove_problems(field, at)
        elif kind == "array":
            items = field.get("items", {})
            if items.get("type") == "object":
                out += foxglove_problems(items, at + "[]")
            elif items.get("type") not in ("boolean", "string", "number", "integer"):
                out.append(f"{at}: array items of type {items.get('type')!r}")
        elif kind not in ("boolean", "string", "number", "integer"):
            out.append(f"{at}: type {kind!r}")
    return out
