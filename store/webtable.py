"""A generation's web records as columns: what a reader of a large store keeps (design §9, issue 25).

A manifest lists one record per web (``a``, ``b``, ``a_sha``, ``b_sha``, ``key``, ``chunk``,
counts; see :class:`~motionweb.store.generations.Generation`). As Python dicts those cost about
1.5 kB each, so a 381k-frame library's 146,610 webs hold ~0.3 GB in every process that opens the
generation (the app's service and each of its search workers). :class:`WebTable` keeps the same
records as numpy columns: a string field repeated across records (clip paths, hashes, chunks) as
codes into its distinct values, a string field that differs per record (``key``) as one bytes
array, numbers as arrays: about 0.2 kB per web. It is a read-only sequence of the records (a
record is rebuilt as the dict the manifest holds when asked for), and :meth:`ends` gives the
columns a reader indexes by clip without building any record.

Cost: building one is O(webs) (one pass per field); a record costs O(fields); memory O(webs).
"""

from __future__ import annotations

import json
import re
from array import array
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

_MISSING = object()


class _Column:
    """One field of every record. ``kind``: "codes" (``values`` the distinct strings, ``data``
    int32 codes), "bytes" (``data`` an ``S`` array of ASCII strings), "int", "float", "bool",
    "ints" (equal-length lists of ints, ``data`` (W, k)) or "object" (a list, where some records
    lack the field (``_MISSING``) or its values are of mixed or other types)."""

    def __init__(self, kind: str, data: Any, values: list[str] | None = None):
        self.kind, self.data, self.values = kind, data, values

    @classmethod
    def of_strings(cls, distinct: list[str], codes: np.ndarray) -> _Column:
        """A string field, from its distinct values and a code per record ``(W,)``: codes when
        values repeat (at most half are distinct), else one bytes array when they are ASCII."""
        if len(distinct) * 2 > len(codes) and all(v.isascii() and not v.endswith("\x00") for v in distinct):
            return cls("bytes", np.array([v.encode() for v in distinct], dtype=bytes)[codes])
        return cls("codes", codes.astype(np.int32), distinct)

    @classmethod
    def of(cls, values: list[Any]) -> _Column:
        """A field that is not all strings (those are coded as they come: :class:`_Field`), from
        its value per record (``_MISSING`` where a record lacks it)."""
        kinds = {type(v) for v in values}
        if kinds == {bool}:
            return cls("bool", np.array(values, dtype=bool))
        if kinds == {int} and all(-2**63 <= v < 2**63 for v in values):
            return cls("int", np.array(values, dtype=np.int64))
        if kinds == {float, int} or kinds == {float}:
            return cls("float", np.array(values, dtype=np.float64))
        if kinds == {list} and len({len(v) for v in values}) == 1 \
                and all(type(x) is int and -2**63 <= x < 2**63 for v in values for x in v):
            return cls("ints", np.array(values, dtype=np.int64).reshape(len(values), -1))
        return cls("object", values)

    def get(self, i: int) -> Any:
        if self.kind == "codes":
            return self.values[self.data[i]]
        if self.kind == "bytes":
            return self.data[i].decode()
        if self.kind == "int":
            return int(self.data[i])
        if self.kind == "float":
            return float(self.data[i])
        if self.kind == "bool":
            return bool(self.data[i])
        if self.kind == "ints":
            return [int(x) for x in self.data[i]]
        return self.data[i]


class _Field:
    """A column being filled a batch of records at a time: strings coded as they come (a
    record's string is not kept, only its code), anything else kept as a value until
    :meth:`finish`."""

    def __init__(self, missing_before: int):
        self.distinct: dict[str, int] | None = {} if missing_before == 0 else None
        self.codes = array("q")
        self.generic: list[Any] | None = None if missing_before == 0 else [_MISSING] * missing_before

    def extend(self, values: list[Any]) -> None:
        if self.generic is None:
            if set(map(type, values)) <= {str}:
                d = self.distinct
                self.codes.extend([d.setdefault(v, len(d)) for v in values])  # a new string gets the next code
                return
            distinct = list(self.distinct)
            self.generic, self.distinct = [distinct[c] for c in self.codes], None
        self.generic.extend(values)

    def finish(self) -> _Column:
        if self.generic is None:
            return _Column.of_strings(list(self.distinct), np.frombuffer(self.codes, np.int64))
        return _Column.of(self.generic)


class TableBuilder:
    """Builds a :class:`WebTable` from records given one at a time (the manifest's web records as
    they are parsed: see :func:`parse_manifest`), holding at most ``batch`` of them; per record
    afterwards its codes and numbers only."""

    def __init__(self, batch: int = 4096) -> None:
        self.n, self.batch = 0, batch
        self.fields: dict[str, _Field] = {}
        self._pending: list[dict[str, Any]] = []

    def add(self, rec: dict[str, Any]) -> None:
        if not isinstance(rec, dict):
            raise ValueError(f"web record {self.n + len(self._pending)} is a JSON {type(rec).__name__}, "  # noqa: TRY004 - damage to a manifest, not a caller's type error
                             "not an object")
        self._pending.append(rec)
        if len(self._pending) >= self.batch:
            self._flush()

    def _flush(self) -> None:
        recs, self._pending = self._pending, []
        for k in dict.fromkeys(k for r in recs for k in r):
            if k not in self.fields:
                self.fields[k] = _Field(self.n)
        for k, f in self.fields.items():
            f.extend([r.get(k, _MISSING) for r in recs])
        self.n += len(recs)

    def finish(self) -> WebTable:
        self._flush()
        table = WebTable.__new__(WebTable)
        table._n, table._fields = self.n, list(self.fields)
        table._columns = {k: f.finish() for k, f in self.fields.items()}
        return table


_WS = re.compile(r"[ \t\n\r]*")


def parse_manifest(text: str, skip: tuple[str, ...] = ("checksums",)) -> dict[str, Any]:
    """A manifest's JSON object (any other JSON value as it is), its ``webs`` as a :class:`WebTable` built record by record (no
    list of record dicts is ever held) and the fields in ``skip`` parsed and dropped.
    ValueError (a ``json.JSONDecodeError`` naming the position) for text that is not a JSON
    object. Cost O(bytes); memory O(the table) besides ``text``."""
    if not text.lstrip(" \t\n\r").startswith("{"):
        return json.loads(text)  # not an object: the caller says what it holds
    dec = json.JSONDecoder()

    def at(i: int, char: str) -> int:
        i = _WS.match(text, i).end()
        if not text.startswith(char, i):
            raise json.JSONDecodeError(f"expected {char!r}", text, i)
        return _WS.match(text, i + 1).end()

    def items(i: int, close: str, each) -> int:  # the members of an array or object
        if text.startswith(close, i):
            return i + 1
        while True:
            i = _WS.match(text, each(i)).end()
            if text.startswith(close, i):
                return i + 1
            i = at(i, ",")

    out: dict[str, Any] = {}

    def member(i: int) -> int:
        key, i = dec.raw_decode(text, i)
        if not isinstance(key, str):
            raise json.JSONDecodeError("expected a field name", text, i)
        i = at(i, ":")
        if key == "webs" and text.startswith("[", i):
            builder = TableBuilder()

            def record(j: int) -> int:
                rec, j = dec.raw_decode(text, j)
                builder.add(rec)
                return j

            i = items(_WS.match(text, i + 1).end(), "]", record)
            out[key] = builder.finish()
        else:
            value, i = dec.raw_decode(text, i)
            if key not in skip:
                out[key] = value
            del value  # a skipped field is held only while it is parsed
        return i

    i = items(at(0, "{"), "}", member)
    if _WS.match(text, i).end() != len(text):
        raise json.JSONDecodeError("extra data", text, i)
    return out


class WebTable(Sequence[dict[str, Any]]):
    """The web records of a manifest, read-only, as columns (see the module docstring).

    ``table[i]`` is record ``i`` as the manifest's dict (a new dict each time: changing it does
    not change the table); iteration yields them in the manifest's order."""

    def __init__(self, records: Sequence[dict[str, Any]]):
        builder = TableBuilder()
        for r in records:
            builder.add(r)
        built = builder.finish()
        self._n, self._fields, self._columns = built._n, built._fields, built._columns

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i):  # type: ignore[override]
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(self._n))]
        if i < 0:
            i += self._n
        if not 0 <= i < self._n:
            raise IndexError(f"web record {i} of {self._n}")
        out = {}
        for f in self._fields:
            v = self._columns[f].get(i)
            if v is not _MISSING:
                out[f] = v
        return out

    def __iter__(self) -> Iterator[dict[str, Any]]:
        return (self[i] for i in range(self._n))

    def __eq__(self, other: object) -> bool:
        if isinstance(other, Sequence) and not isinstance(other, str | bytes):
            return len(self) == len(other) and all(x == y for x, y in zip(self, other, strict=True))
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]

    def strings(self, field: str) -> tuple[list[str], np.ndarray]:
        """(distinct values, int32 code per record ``(W,)``) of a string field present in every
        record; ValueError otherwise."""
        col = self._columns.get(field)
        if col is None or self._n == 0:
            return [], np.zeros(0, np.int32)
        if col.kind == "codes":
            return col.values, col.data
        if col.kind == "bytes":
            values, codes = np.unique(col.data, return_inverse=True)
            return [v.decode() for v in values], codes.astype(np.int32)
        raise ValueError(f"web records: field {field!r} is not a string in every record")

    def ends(self, paths: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """The clip indices into ``paths`` of every record's ``a`` and ``b``, ``(W,)`` int32 each
        (-1: a path not in ``paths``)."""
        at = {p: i for i, p in enumerate(paths)}
        out = []
        for field in ("a", "b"):
            values, codes = self.strings(field)
            lookup = np.array([at.get(v, -1) for v in values], dtype=np.int32)
            out.append(lookup[codes] if len(values) else np.zeros(self._n, np.int32))
        return out[0], out[1]

    @property
    def nbytes(self) -> int:
        """Bytes held by the columns' arrays (their distinct strings counted by length)."""
        total = 0
        for col in self._columns.values():
            if isinstance(col.data, np.ndarray):
                total += col.data.nbytes
            else:
                total += 8 * len(col.data)
            if col.kind == "codes":
                total += sum(len(v) + 49 for v in col.values)
        return total
