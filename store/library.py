"""The CMRT library and PCA bases: `LibraryRepository` (the contract) and `SqlLibrary`.

The library is append-only: a CMRT is added, never updated or deleted (no route, command or
store call does either). So `SqlLibrary` keeps what it has read (the library's hot path, a
query answered from one family's keys and two members, is then one indexed count instead of
decoding every member's JSON at every request): records by id for good, and each family's
keys checked at every read against the store's count and newest time of that family, so a
CMRT another process added is seen at the next read."""

from __future__ import annotations

import abc
import math
import uuid
from collections.abc import Mapping, Sequence
from typing import Any

from sqlalchemy import Text, and_, bindparam, cast, func, select
from sqlalchemy.exc import IntegrityError

from cmrt.lru import LRU
from store.errors import Conflict, NotFound
from store.models import BasisRow, CmrtParameterRow, CmrtRow, CmrtVerificationRow, JobRow
from store.records import (
    CMRT_ENTRY_FIELDS,
    WINNERS,
    BasisRecord,
    CmrtEntry,
    CmrtKey,
    CmrtRecord,
    VerificationRecord,
)
from store.sql import (
    SqlBase,
    _exact_eps,
    _json,
    _num,
    _opt_num,
    field_names,
    row_record,
)


class LibraryRepository(abc.ABC):
    """Library CMRTs (one `CmrtEntry` each, task parameters queryable by name) and PCA bases."""

    # ---- CMRT library -------------------------------------------------------------------
    @abc.abstractmethod
    def add_cmrt(self, entry: CmrtEntry) -> str:
        """Add a library CMRT and return its id. Every task parameter becomes queryable by
        name (`find_cmrts`). Raises Conflict if `entry.job_id` names no job; ValueError for
        non-finite task parameters, clip times or objective, or an unknown `winner`."""

    @abc.abstractmethod
    def job_cmrt(self, job_id: str) -> CmrtRecord | None:
        """The library CMRT a job added (`entry.job_id == job_id`), None if it added none.
        One indexed lookup (cmrts.job_id); a job adds at most one entry."""

    @abc.abstractmethod
    def get_cmrt(self, cmrt_id: str) -> CmrtRecord:
        """The CMRT; raises NotFound."""

    @abc.abstractmethod
    def find_cmrts(
        self,
        family: str,
        params: Mapping[str, float],
        *,
        tolerance: float | Mapping[str, float] | None = None,
        character: Mapping[str, Any] | None = None,
        limit: int | None = None,
    ) -> list[CmrtRecord]:
        """Library CMRTs of `family` matching the task parameters `params`.

        Without `tolerance`: every named parameter equal (to 1e-9 relative). With a tolerance
        (one number, or one per name; names not in the mapping must match exactly): every
        named parameter within +-tolerance, ordered nearest first by the Euclidean distance
        over the named parameters, each difference divided by its tolerance (ties: lower
        objective first). Only CMRTs having all named parameters match. `character` keeps
        entries whose character has the given items (e.g. {"height": 1.75}).
        """

    @abc.abstractmethod
    def find_cmrt_keys(self, family: str, params: Mapping[str, float], *,
                       tolerance: float | Mapping[str, float] | None = None,
                       character: Mapping[str, Any] | None = None,
                       limit: int | None = None) -> list[CmrtKey]:
        """`find_cmrts`'s CMRTs, in its order, as keys: their summary without curve, spline
        or spec (a list of matches reads no CMRT's JSON beyond its family's keys)."""

    @abc.abstractmethod
    def list_cmrts(
        self, family: str | None = None, *, limit: int | None = None, offset: int = 0
    ) -> tuple[list[CmrtRecord], int]:
        """Library CMRTs (of one family if given), newest first, and the total count."""

    @abc.abstractmethod
    def cmrt_keys(self, family: str) -> list[CmrtKey]:
        """Every library CMRT of `family` as a `CmrtKey` (task parameters, objective, spline
        layout; no curve or spec), newest first as `list_cmrts` orders them."""

    @abc.abstractmethod
    def cmrt_families(self) -> list[tuple[str, int]]:
        """Every family of the library with its number of CMRTs, by name (one grouped,
        indexed query: the library page's list of families)."""

    # ---- verified answers ---------------------------------------------------------------
    @abc.abstractmethod
    def add_verification(
        self, *, family: str, spec_hash: str, params_hash: str, source: str,
        members: Sequence[str], outcome: Mapping[str, Any],
    ) -> VerificationRecord:
        """Keep the simulated outcome of CMRT `params_hash` on spec `spec_hash` and return the
        stored record: the first stored for that pair wins (a concurrent second one gets the
        first back, so every reader sees one outcome)."""

    @abc.abstractmethod
    def get_verification(self, spec_hash: str, params_hash: str) -> VerificationRecord | None:
        """The stored outcome of CMRT `params_hash` on spec `spec_hash`, None if never
        simulated (one indexed lookup)."""

    # ---- PCA bases ----------------------------------------------------------------------
    @abc.abstractmethod
    def add_basis(
        self,
        *,
        family: str,
        k: int,
        mean: Sequence[float],
        components: Sequence[Sequence[float]],
        variance_explained: Sequence[float],
        members: Sequence[str],
        box: Any = None,
    ) -> str:
        """Store a PCA basis and return its id. ValueError if `components` has not `k` rows
        of the length of `mean`."""

    @abc.abstractmethod
    def list_bases(
        self, family: str | None = None, *, limit: int | None = None, offset: int = 0
    ) -> tuple[list[BasisRecord], int]:
        """PCA bases (of one family if given), newest first, and their total count."""

    @abc.abstractmethod
    def get_basis(self, basis_id: str) -> BasisRecord:
        """The basis; raises NotFound."""


# JSON columns keep a Python None as the JSON text `null`, not SQL NULL.
_HAS_SPEC = and_(CmrtRow.spec.is_not(None), cast(CmrtRow.spec, Text) != "null")
#: A family's keys (`cmrt_keys`), newest first, and what tells whether kept keys are current:
#: the family's count and newest time (rows are only ever added). Built once: building a
#: statement costs more than running it on a warm database.
_FAMILY_KEYS = (
    select(CmrtRow.id, CmrtRow.task_parameters, CmrtRow.objective, CmrtRow.knots,
           CmrtRow.values, _HAS_SPEC, CmrtRow.created_at, CmrtRow.preparation, CmrtRow.decay,
           CmrtRow.character, CmrtRow.family, CmrtRow.objective_without, CmrtRow.winner,
           CmrtRow.fell, CmrtRow.job_id)
    .where(CmrtRow.family == bindparam("family")).order_by(CmrtRow.created_at.desc(), CmrtRow.id))
_FAMILY_STAMP = select(func.count(), func.max(CmrtRow.created_at)).where(
    CmrtRow.family == bindparam("family"))

#: Library records by id, as Core rows in `CmrtRecord`'s field order (no ORM objects made).
_RECORDS = select(*(CmrtRow.__table__.c[name] for name in field_names(CmrtRecord))).where(
    CmrtRow.id.in_(bindparam("ids", expanding=True)))

#: Library records kept in memory per repository (about 17 kB each with curve and spec): the
#: members the recent queries read, 17 MB at the most. Not more: a kept record's curve lists
#: are what a full garbage collection of the API process walks (4,096 kept records made one
#: 3-4x longer), and a record read anew costs 0.4 ms.
RECORDS_KEPT = 1024
#: Families whose keys are kept (about 60 kB for 50 members).
FAMILIES_KEPT = 512


class SqlLibrary(SqlBase, LibraryRepository):
    def _kept(self, what: str, size: int) -> LRU[str, Any]:
        """This repository's `what` cache (made on first use: SqlBase.__init__ is the
        repository's one __init__); thread-safe, as the service reads on several threads."""
        kept = self.__dict__.get(what)
        if kept is None:
            kept = self.__dict__.setdefault(what, LRU(size))
        return kept

    def _records(self, ids: Sequence[str]) -> dict[str, CmrtRecord]:
        """The records of `ids` that exist: kept ones from memory, the rest in one query."""
        kept = self._kept("_kept_records", RECORDS_KEPT)
        out: dict[str, CmrtRecord] = {}
        missing = []
        for cid in ids:
            rec = kept.get(cid)
            if rec is None:
                missing.append(cid)
            else:
                out[cid] = rec
        if missing:
            with self._read_core() as conn:
                got = [CmrtRecord(**row._mapping)
                       for row in conn.execute(_RECORDS, {"ids": missing})]
            for r in got:
                kept.put(r.id, r)
            out.update((r.id, r) for r in got)
        return out

    # ---- CMRT library -------------------------------------------------------------------
    def add_cmrt(self, entry):
        e = entry
        tp = {}
        for k, v in e.task_parameters.items():
            if not isinstance(k, str) or not 0 < len(k) <= 64:
                raise ValueError(f"task parameter name {k!r}: 1..64 characters")
            tp[k] = _num(v, f"task parameter {k!r}", allow_inf=False)
        if e.winner not in WINNERS:
            raise ValueError(f"winner: {e.winner!r} is not one of {', '.join(WINNERS)}")
        values = {name: getattr(e, name) for name in CMRT_ENTRY_FIELDS}
        values.update(
            character=_json(dict(e.character), "character"), task_parameters=tp,
            preparation=_num(e.preparation, "preparation", allow_inf=False),
            duration=_num(e.duration, "duration", allow_inf=False),
            decay=_num(e.decay, "decay", allow_inf=False), params=_json(e.params, "params"),
            knots=_json(e.knots, "knots"), values=_json(e.values, "values"),
            curve=_json(e.curve, "curve"), objective=_num(e.objective, "objective"),
            objective_without=_opt_num(e.objective_without, "objective_without"),
            fell=bool(e.fell),
            fell_without=None if e.fell_without is None else bool(e.fell_without),
            spec=_json(None if e.spec is None else dict(e.spec), "spec"),
        )  # fmt: skip
        row = CmrtRow(id=str(uuid.uuid4()), created_at=self._clock(), **values)
        with self._write() as s:
            if e.job_id is not None and s.get(JobRow, e.job_id) is None:
                raise Conflict(f"job {e.job_id} not found")
            s.add(row)
            s.flush()
            s.add_all(CmrtParameterRow(cmrt_id=row.id, name=k, value=v) for k, v in tp.items())
            return row.id

    def job_cmrt(self, job_id):
        with self._read() as s:
            row = s.scalars(
                select(CmrtRow).where(CmrtRow.job_id == job_id)
                .order_by(CmrtRow.created_at).limit(1)
            ).one_or_none()
            return None if row is None else row_record(CmrtRecord, row)

    def get_cmrt(self, cmrt_id):
        rec = self._records([cmrt_id]).get(cmrt_id)
        if rec is None:
            raise NotFound(f"CMRT {cmrt_id!a} not found")
        return rec

    def find_cmrts(self, family, params, *, tolerance=None, character=None, limit=None):
        keys = self.find_cmrt_keys(family, params, tolerance=tolerance, character=character,
                                   limit=limit)
        by_id = self._records([k.id for k in keys])
        return [by_id[k.id] for k in keys if k.id in by_id]

    def find_cmrt_keys(self, family, params, *, tolerance=None, character=None, limit=None):
        target = {k: _num(v, f"parameter {k!r}", allow_inf=False) for k, v in params.items()}
        tol: dict[str, float | None] = {}
        for name in target:
            t = tolerance.get(name) if isinstance(tolerance, Mapping) else tolerance
            if t is not None and (not math.isfinite(t) or t < 0):
                raise ValueError(f"tolerance for {name!r} must be finite and >= 0")
            tol[name] = t
        # Kept keys (checked against the store) hold every member's task parameters: the
        # same numbers as the parameter rows, compared as SQL's `BETWEEN` would.
        found: list[tuple[float, CmrtKey]] = []
        for k in self.cmrt_keys(family):
            total = 0.0
            for name, v in target.items():
                half = tol[name] if tol[name] is not None else _exact_eps(v)
                x = k.task_parameters.get(name)
                if x is None or not v - half <= x <= v + half:
                    break
                d, t = x - v, tol[name]
                total += (d / t) ** 2 if t else (0.0 if abs(d) <= _exact_eps(v) else math.inf)
            else:
                if not character or _character_matches(k.character or {}, character):
                    found.append((math.sqrt(total), k))
        found.sort(key=lambda dk: (dk[0], dk[1].objective, dk[1].created_at, dk[1].id))
        keys = [k for _, k in found]
        return keys if limit is None else keys[:limit]

    def list_cmrts(self, family=None, *, limit=None, offset=0):
        conds = [] if family is None else [CmrtRow.family == family]
        with self._read() as s:
            total = s.scalar(select(func.count()).select_from(CmrtRow).where(*conds)) or 0
            q = select(CmrtRow).where(*conds).order_by(CmrtRow.created_at.desc(), CmrtRow.id)
            rows = s.scalars(q.limit(limit).offset(offset)).all()
            return [row_record(CmrtRecord, r) for r in rows], int(total)

    def cmrt_keys(self, family):
        kept = self._kept("_kept_keys", FAMILIES_KEPT)
        with self._read_core() as conn:
            stamp = tuple(conn.execute(_FAMILY_STAMP, {"family": family}).one())
            got = kept.get(family)
            if got is not None and got[0] == stamp:
                return list(got[1])
            rows = conn.execute(_FAMILY_KEYS, {"family": family}).all()
        keys = [
            CmrtKey(id=cid, task_parameters={k: float(v) for k, v in tp.items()},
                    objective=float(obj), knots=len(knots),
                    vertical=bool(values) and isinstance(values[0], list),
                    has_spec=bool(spec), created_at=created, preparation=float(prep),
                    decay=float(dec), character=character, family=fam,
                    objective_without=without, winner=winner, fell=bool(fell), job_id=job)
            for (cid, tp, obj, knots, values, spec, created, prep, dec, character, fam, without,
                 winner, fell, job) in rows
        ]
        kept.put(family, (stamp, keys))
        return list(keys)

    def cmrt_families(self):
        with self._read() as s:
            rows = s.execute(select(CmrtRow.family, func.count()).group_by(CmrtRow.family)
                             .order_by(CmrtRow.family)).all()
            return [(str(f), int(n)) for f, n in rows]

    # ---- verified answers ---------------------------------------------------------------
    def add_verification(self, *, family, spec_hash, params_hash, source, members, outcome):
        row = CmrtVerificationRow(
            id=str(uuid.uuid4()), family=family, spec_hash=spec_hash, params_hash=params_hash,
            source=source, members=[str(m) for m in members],
            outcome=_json(dict(outcome), "outcome"), created_at=self._clock(),
        )  # fmt: skip
        try:
            with self._write() as s:
                s.add(row)
        except IntegrityError:  # stored meanwhile by another request: that one is the answer
            pass
        got = self.get_verification(spec_hash, params_hash)
        assert got is not None
        return got

    def get_verification(self, spec_hash, params_hash):
        with self._read() as s:
            row = s.scalars(select(CmrtVerificationRow).where(
                CmrtVerificationRow.spec_hash == spec_hash,
                CmrtVerificationRow.params_hash == params_hash)).one_or_none()
            return None if row is None else _verification_record(row)

    # ---- PCA bases ----------------------------------------------------------------------
    def add_basis(self, *, family, k, mean, components, variance_explained, members, box=None):
        m = _json(mean, "mean")
        comps = _json(components, "components")
        if k < 1 or len(comps) != k or any(len(row) != len(m) for row in comps):
            raise ValueError(f"components must be {k} rows of length {len(m)}")
        row = BasisRow(
            id=str(uuid.uuid4()), family=family, k=int(k), mean=m, components=comps,
            variance_explained=_json(variance_explained, "variance_explained"),
            members=[str(x) for x in members], box=_json(box, "box"), created_at=self._clock(),
        )  # fmt: skip
        with self._write() as s:
            s.add(row)
            return row.id

    def list_bases(self, family=None, *, limit=None, offset=0):
        conds = [] if family is None else [BasisRow.family == family]
        with self._read() as s:
            total = s.scalar(select(func.count()).select_from(BasisRow).where(*conds)) or 0
            q = select(BasisRow).where(*conds).order_by(BasisRow.created_at.desc(), BasisRow.id)
            rows = s.scalars(q.limit(limit).offset(offset)).all()
            return [row_record(BasisRecord, b) for b in rows], int(total)

    def get_basis(self, basis_id):
        with self._read() as s:
            row = s.get(BasisRow, basis_id)
            if row is None:
                raise NotFound(f"basis {basis_id!a} not found")
            return row_record(BasisRecord, row)



def _verification_record(v: CmrtVerificationRow) -> VerificationRecord:
    return row_record(VerificationRecord, v, members=list(v.members), outcome=dict(v.outcome))


def _character_matches(stored: Mapping[str, Any], wanted: Mapping[str, Any]) -> bool:
    for key, want in wanted.items():
        have = stored.get(key)
        if isinstance(want, (int, float)) and isinstance(have, (int, float)):
            if abs(float(have) - float(want)) > _exact_eps(float(want)):
                return False
        elif have != want:
            return False
    return True



