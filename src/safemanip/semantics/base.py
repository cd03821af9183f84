"""Types shared by the semantic backends and the selectors that use them."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, Sequence

import numpy as np

from safemanip.selection.base import SceneView


VLM_BACKENDS = ("semantic", "openai")
"""The semantic backends by name (``--vlm-backend``): the offline classifier and any OpenAI-compatible server."""


class BackendError(RuntimeError):
    """A backend could not produce a valid answer (network, server, cache miss, malformed answer).

    Selectors catch this and fall back; the message says what went wrong and, where possible, what to fix.
    """


class SchemaError(BackendError):
    """An answer was parsed but does not fit the scene (unknown label, wrong count, bad enum value...)."""


def object_label(object_id: int, name: str) -> str:
    """The label used in prompts, schemas and image annotations, e.g. ``"3: red mug"``.

    The id prefix keeps labels unique when a scene holds two objects with the same name.
    """
    return f"{object_id}: {name}"


@dataclass
class ObjectQuery:
    """One relevant-object question: which k objects matter now?"""

    view: SceneView
    k: int
    order: list[int]
    """Object ids sorted by horizontal distance to the end-effector, nearest first."""
    task: str | None = None
    """Task description; None means the default task."""
    images: list[bytes] | None = None
    """PNG-encoded annotated frames, oldest first (None when no renderer is available)."""

    @property
    def labels(self) -> list[str]:
        """Labels in distance order (position 0 = nearest to the end-effector)."""
        return [object_label(i, self.view.names[i]) for i in self.order]

    @property
    def n_select(self) -> int:
        return min(self.k, len(self.view.names))


@dataclass
class ObjectAnswer:
    ids: list[int]
    explanation: str = ""
    image_description: str = ""
    raw: dict | None = None
    """The parsed structured answer as returned (VLM backends)."""
    cached: bool = False


@dataclass
class ConstraintQuery:
    """One constraint question: which constraint type does each object in the scene get?"""

    names: tuple[str, ...]
    task: str | None = None
    images: list[bytes] | None = None

    @property
    def labels(self) -> list[str]:
        return [object_label(i, n) for i, n in enumerate(self.names)]


@dataclass
class ConstraintAnswer:
    constraints: list[str]
    """One of CONSTRAINT_TYPES per object, in scene order."""
    explanations: list[str] = field(default_factory=list)
    probabilities: np.ndarray | None = None
    """(N, 3) class probabilities (fragile, soft, durable) when the backend has them."""
    raw: dict | None = None
    cached: bool = False


class Backend(Protocol):
    """What a selector needs from a backend. Implementations: OpenAIBackend, SemanticBackend."""

    name: str
    needs_images: bool
    """True when the backend wants rendered frames in ObjectQuery.images."""

    def prepare(self, names: Sequence[str]) -> None:
        """Called once per scene (at reset) so per-name work happens before the control loop."""
        ...

    def select_objects(self, query: ObjectQuery) -> ObjectAnswer: ...

    def assign_constraints(self, query: ConstraintQuery) -> ConstraintAnswer: ...

    def describe(self) -> dict:
        """Identity for result logs (model, prompt version, ...). Never contains secrets."""
        ...
