"""The canonical text of a JSON document and its hash: the one form in which a task spec (or a
family request) crosses a process boundary and is stored, and the key the processes cache its
typed form under (`sim.spec.CanonicalSpec`, `optim.objective.SPECS`).

Canonical = sorted keys, no whitespace, Python's float repr (exact round trip); the hash is the
SHA-256 of that text (hex). Pure standard library, so the store, the service and the numerics
all compute the same hash without importing each other.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any


def canonical_json(document: Mapping[str, Any]) -> str:
    """The document's canonical JSON text (sorted keys, compact separators)."""
    return json.dumps(document, sort_keys=True, separators=(",", ":"))


def text_hash(text: str) -> str:
    """SHA-256 (hex, 64 characters) of a canonical text."""
    return hashlib.sha256(text.encode()).hexdigest()


def document_hash(document: Mapping[str, Any]) -> str:
    """The hash of a document's canonical text."""
    return text_hash(canonical_json(document))


__all__ = ["canonical_json", "document_hash", "text_hash"]
