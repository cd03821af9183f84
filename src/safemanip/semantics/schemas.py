"""JSON schemas for the structured answers, and validation of answers against the scene.

The schemas are built per query because the allowed object labels are an enum of the scene's labels:
with strict structured outputs the server can then only emit labels that exist. They follow the
strict-mode rules (every property required, ``additionalProperties: false``) so they are accepted by
OpenAI and by the grammar-constrained decoders of vLLM / llama.cpp / Ollama. Validation is repeated
on our side anyway, because a compatible server may ignore the schema and because cached answers are
re-checked when read back.
"""

from __future__ import annotations

import re
from typing import Any, Sequence

from safemanip.scene.catalog import CONSTRAINT_TYPES
from safemanip.semantics.base import SchemaError

SCHEMA_VERSION = "1"
"""Bumped whenever a schema below changes shape; cached answers recorded under another version are not used."""
OBJECT_SCHEMA_NAME = "relevant_objects"
CONSTRAINT_SCHEMA_NAME = "object_constraints"


def object_selection_schema(labels: Sequence[str], k: int) -> dict:
    """Schema of an object-selection answer: exactly ``k`` labels out of ``labels``.

    The free-text fields come first so that a model decoding left to right describes the scene and
    reasons before it commits to the selection.
    """
    labels = list(labels)
    if k < 1 or k > len(labels):
        raise ValueError(f"k must be between 1 and the number of objects ({len(labels)}), got {k}")
    if len(set(labels)) != len(labels):
        raise ValueError(f"object labels must be unique, got {labels}")
    return {
        "type": "object",
        "properties": {
            "image_description": {"type": "string"},
            "explanation": {"type": "string"},
            "objects": {
                "type": "array",
                "items": {"type": "string", "enum": labels},
                "minItems": k,
                "maxItems": k,
            },
        },
        "required": ["image_description", "explanation", "objects"],
        "additionalProperties": False,
    }


def constraint_schema(labels: Sequence[str]) -> dict:
    """Schema of a constraint answer: one entry per object label, constraint from CONSTRAINT_TYPES.

    Keyed by label (rather than a list) so that "one entry for every object, no duplicates" is
    enforced by the schema itself instead of relying on array-length keywords.
    """
    labels = list(labels)
    if not labels:
        raise ValueError("constraint schema needs at least one object label")
    if len(set(labels)) != len(labels):
        raise ValueError(f"object labels must be unique, got {labels}")
    entry = {
        "type": "object",
        "properties": {
            "explanation": {"type": "string"},
            "constraint": {"type": "string", "enum": list(CONSTRAINT_TYPES)},
        },
        "required": ["explanation", "constraint"],
        "additionalProperties": False,
    }
    return {
        "type": "object",
        "properties": {
            "constraints": {
                "type": "object",
                "properties": {label: entry for label in labels},
                "required": labels,
                "additionalProperties": False,
            }
        },
        "required": ["constraints"],
        "additionalProperties": False,
    }


_TYPES: dict[str, type | tuple[type, ...]] = {
    "object": dict, "array": list, "string": str, "boolean": bool, "number": (int, float), "integer": int,
}


def validate(instance: Any, schema: dict, path: str = "$") -> None:
    """Check ``instance`` against the subset of JSON Schema used here; raise SchemaError naming the spot.

    Covers type, enum, properties/required/additionalProperties, items/minItems/maxItems. A small
    validator is enough for our own schemas and avoids a dependency.
    """
    expected = schema.get("type")
    if expected is not None:
        py = _TYPES[expected]
        # bool is an int in Python; a JSON true is not a number
        if not isinstance(instance, py) or (expected in ("number", "integer") and isinstance(instance, bool)):
            raise SchemaError(f"{path}: expected {expected}, got {type(instance).__name__} {_short(instance)}")
    if "enum" in schema and instance not in schema["enum"]:
        raise SchemaError(f"{path}: {_short(instance)} is not one of {schema['enum']}")
    if expected == "object":
        props = schema.get("properties", {})
        for key in schema.get("required", []):
            if key not in instance:
                raise SchemaError(f"{path}: missing required key {key!r}")
        if schema.get("additionalProperties", True) is False:
            extra = [key for key in instance if key not in props]
            if extra:
                raise SchemaError(f"{path}: unexpected keys {extra}")
        for key, sub in props.items():
            if key in instance:
                validate(instance[key], sub, f"{path}.{key}")
    elif expected == "array":
        if "minItems" in schema and len(instance) < schema["minItems"]:
            raise SchemaError(f"{path}: {len(instance)} items, need at least {schema['minItems']}")
        if "maxItems" in schema and len(instance) > schema["maxItems"]:
            raise SchemaError(f"{path}: {len(instance)} items, allowed at most {schema['maxItems']}")
        if "items" in schema:
            for i, item in enumerate(instance):
                validate(item, schema["items"], f"{path}[{i}]")


def check_strict_compatible(schema: dict, path: str = "$") -> None:
    """Raise ValueError if ``schema`` breaks the strict structured-output rules (all keys required, no extras)."""
    if schema.get("type") == "object":
        props = schema.get("properties", {})
        if schema.get("additionalProperties") is not False:
            raise ValueError(f"{path}: strict mode needs additionalProperties: false")
        if sorted(schema.get("required", [])) != sorted(props):
            raise ValueError(f"{path}: strict mode needs every property listed in 'required'")
        for key, sub in props.items():
            check_strict_compatible(sub, f"{path}.{key}")
    elif schema.get("type") == "array" and "items" in schema:
        check_strict_compatible(schema["items"], f"{path}[]")


def resolve_label(item: Any, labels: Sequence[str]) -> str:
    """The scene label an answer's object entry means, or SchemaError.

    Served models that do not enforce the schema write the label the way a person would: ``"3: red mug"``,
    ``"3"``, ``3``, ``"Red Mug"``, ``"object 3 (red mug)"``. An entry is resolved only when it names exactly one label:
    by its exact label, by an id alone, by an id whose name (if given) agrees, or by a name that exactly one object
    has (ignoring case and spacing). Anything else (an unknown or misspelt name, an id out of range, a name two
    objects share, an id that contradicts its name) is refused, never guessed."""
    labels = list(labels)
    if isinstance(item, bool) or not isinstance(item, (str, int)):
        raise SchemaError(f"object entry {_short(item)} is neither a label nor an id")
    if isinstance(item, str) and item in labels:
        return item
    names = {i: _plain(label.split(":", 1)[1]) for i, label in enumerate(labels)}
    text = str(item).strip()
    match = re.fullmatch(r"(?:object\s*|id\s*|#)?(\d+)\s*(?:[:.)\-]\s*|\s+|\()?\s*(.*?)\)?", text, flags=re.IGNORECASE)
    if match and match.group(1) is not None:
        i, rest = int(match.group(1)), _plain(match.group(2) or "")
        if i in names and (not rest or rest == names[i]):
            return labels[i]
        raise SchemaError(f"object entry {_short(item)} names no object of this scene (labels {labels})")
    found = [i for i, name in names.items() if name == _plain(text)]
    if len(found) == 1:
        return labels[found[0]]
    if found:
        raise SchemaError(f"object entry {_short(item)} is ambiguous: {len(found)} objects have that name; give the id")
    raise SchemaError(f"object entry {_short(item)} names no object of this scene (labels {labels})")


def _plain(name: str) -> str:
    return " ".join(re.findall(r"[a-z0-9]+", str(name).lower()))


def normalize_object_answer(answer: Any, labels: Sequence[str], k: int) -> Any:
    """What a served model meant, in the schema's form: entries resolved to labels (``resolve_label``), repeats of
    one object dropped, missing free-text fields empty and unknown keys ignored. Too few distinct objects after that
    stays an error (the selector falls back for that query), and so do too many (the strict validation after it)."""
    if not isinstance(answer, dict) or not isinstance(answer.get("objects"), list):
        return answer
    chosen: list[str] = []
    for item in answer["objects"]:
        label = resolve_label(item, labels)
        if label not in chosen:
            chosen.append(label)
    if len(chosen) < k:
        raise SchemaError(f"$.objects: {len(chosen)} distinct objects ({chosen}), the answer must name {k}")
    return {"image_description": str(answer.get("image_description") or ""),
            "explanation": str(answer.get("explanation") or ""), "objects": chosen}


def parse_object_answer(answer: Any, labels: Sequence[str], k: int) -> tuple[list[int], str, str]:
    """Validate an object-selection answer; return (object ids, explanation, image_description).

    Labels are ``"<id>: <name>"``; the id is read back from the label the answer chose. An answer that names the
    objects loosely is first resolved by ``normalize_object_answer``; more than k objects is out of schema.
    """
    labels = list(labels)
    answer = normalize_object_answer(answer, labels, k)
    validate(answer, object_selection_schema(labels, k))
    chosen = answer["objects"]
    if len(set(chosen)) != len(chosen):
        raise SchemaError(f"$.objects: labels must be distinct, got {chosen}")
    ids = [int(label.split(":", 1)[0]) for label in chosen]
    return ids, answer["explanation"], answer["image_description"]


def normalize_constraint_answer(answer: Any, labels: Sequence[str]) -> Any:
    """What a served model meant, in the schema's form: keys resolved to labels (``resolve_label``), a constraint
    written loosely (``"No contact"``, ``"no-contact"``) read as its type, a missing explanation empty. Two entries for
    one object that disagree, or an object left out, stay errors (the selector falls back to conservative)."""
    if not isinstance(answer, dict) or not isinstance(answer.get("constraints"), dict):
        return answer
    entries: dict[str, dict] = {}
    for key, entry in answer["constraints"].items():
        label = resolve_label(key, labels)
        if isinstance(entry, str):
            entry = {"constraint": entry}
        if not isinstance(entry, dict):
            raise SchemaError(f"$.constraints[{key!r}]: expected an object with a constraint, got {_short(entry)}")
        constraint = "_".join(re.findall(r"[a-z]+", str(entry.get("constraint", "")).lower()))
        fixed = {"constraint": constraint, "explanation": str(entry.get("explanation") or "")}
        if label in entries and entries[label]["constraint"] != constraint:
            raise SchemaError(f"$.constraints: two different constraints for {label!r}")
        entries[label] = fixed
    return {"constraints": entries}


def parse_constraint_answer(answer: Any, labels: Sequence[str]) -> tuple[list[str], list[str]]:
    """Validate a constraint answer; return (constraint per label, explanation per label) in label order. An answer
    that names the objects or the types loosely is first resolved by ``normalize_constraint_answer``."""
    labels = list(labels)
    answer = normalize_constraint_answer(answer, labels)
    validate(answer, constraint_schema(labels))
    entries = answer["constraints"]
    return [entries[lbl]["constraint"] for lbl in labels], [entries[lbl]["explanation"] for lbl in labels]


def _short(value: Any, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
