"""Named character definitions: `CharacterRepository` (the contract) and `SqlCharacters`
(SQLAlchemy).

A definition is stored as it was given (JSON data; validating it is the caller's: the store
imports no simulator) under a unique name; adding a name that is taken is a `Conflict`, also
when two processes add it at once.
"""

from __future__ import annotations

import abc
import uuid
from collections.abc import Mapping
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError

from cmrt.canonical import document_hash
from store.errors import Conflict, NotFound
from store.models import CharacterRow
from store.records import CharacterRecord
from store.sql import SqlBase, _json, row_record

#: Longest character name (the spec's `character.model` allows 64 characters).
MAX_NAME_LENGTH = 64


class CharacterRepository(abc.ABC):
    """Character definitions kept by name."""

    @abc.abstractmethod
    def add_character(self, name: str, definition: Mapping[str, Any]) -> CharacterRecord:
        """Store `definition` (JSON data) under `name` and return the record; Conflict if the
        name is taken (nothing is changed then); ValueError for a name longer than
        `MAX_NAME_LENGTH` or a definition that is not JSON data."""

    @abc.abstractmethod
    def get_character(self, name: str) -> CharacterRecord:
        """The character stored under `name`; raises NotFound."""

    @abc.abstractmethod
    def list_characters(self, *, limit: int = 50, offset: int = 0
                        ) -> tuple[list[CharacterRecord], int]:
        """Stored characters by name, and their total count."""


def _record(row: CharacterRow) -> CharacterRecord:
    return row_record(CharacterRecord, row)


class SqlCharacters(SqlBase, CharacterRepository):
    """`CharacterRepository` on SQLAlchemy."""

    def add_character(self, name: str, definition: Mapping[str, Any]) -> CharacterRecord:
        if not isinstance(name, str) or not 1 <= len(name) <= MAX_NAME_LENGTH:
            raise ValueError(f"name: 1 to {MAX_NAME_LENGTH} characters")
        doc = _json(dict(definition), "definition")
        row = CharacterRow(id=str(uuid.uuid4()), name=name, definition=doc,
                           definition_hash=document_hash(doc), created_at=self._clock())
        try:
            with self._write() as s:
                if s.scalar(select(CharacterRow.id).where(CharacterRow.name == name)):
                    raise Conflict(f"character {name!a} exists")
                s.add(row)
                s.flush()
                return _record(row)
        except IntegrityError:  # added by another process between the check and the insert
            raise Conflict(f"character {name!a} exists") from None

    def get_character(self, name: str) -> CharacterRecord:
        with self._read() as s:
            row = s.scalars(select(CharacterRow).where(CharacterRow.name == name)).first()
            if row is None:
                raise NotFound(f"character {name!a} not found")
            return _record(row)

    def list_characters(self, *, limit: int = 50, offset: int = 0
                        ) -> tuple[list[CharacterRecord], int]:
        with self._read() as s:
            total = s.scalar(select(func.count()).select_from(CharacterRow)) or 0
            rows = s.scalars(select(CharacterRow).order_by(CharacterRow.name)
                             .limit(limit).offset(offset)).all()
            return [_record(r) for r in rows], total
