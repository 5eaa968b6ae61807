"""The webs of a committed store generation as a web source for the search (KG04 §3.3).

:class:`StoreWebs` maps a clip to the webs touching it, each oriented with that clip as rows,
restricted to one category or not. Opening one reads no web: it indexes the manifest's web
records by clip in numpy over their columns (:class:`~motionweb.store.webtable.WebTable`), O(webs
of the generation) with no Python per web, and holds O(webs) integers; a web is read from the store when a clip it touches
is first asked for, and kept in a cache (:class:`~motionweb.store.cache.LRU`: unbounded by
default, so each web is read once; the service passes one bounded by bytes).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np
from motionweb.store.cache import LRU
from motionweb.store.generations import Generation, load_generation
from motionweb.store.web import MatchWeb, transpose
from motionweb.store.webtable import WebTable
from motionweb.store.zarr_store import MotionStore, StoreError

#: clip key -> [(other clip key, web oriented with the clip as rows)]
WebSource = Mapping[str, Sequence[tuple[str, MatchWeb]]]


class StoreWebs(Mapping[str, list[tuple[str, MatchWeb]]]):
    """A :data:`WebSource` over a committed store generation: the webs touching a clip, oriented
    with it as rows, restricted to clips of ``category`` (None: all). A web is read when first
    asked for and kept in ``cache`` (with its transpose when needed; keyed by the web's content
    key, so scopes and generations sharing a cache share its webs); ``reads`` counts the reads.

    ``keep_webs=False``: webs asked for by clip are read and not kept (a web already in ``cache`` is
    still used). For a reader that keeps what it derives from them instead, in the same bounded
    cache: the service's search keeps each clip's walk graph (``tasks.search.MatchSearch``); kept
    too, a clip's webs and their transposes took about twice its graph's bytes and evicted the
    graphs a search reaches next."""

    def __init__(self, store: MotionStore, generation: Generation | None = None, category: str | None = None,
                 cache: LRU | None = None, keep_webs: bool = True):
        gen = generation if generation is not None else load_generation(store)
        if gen is None:
            raise ValueError(f"store {store.url} was never indexed (no committed generation)")
        self.store, self.generation, self.category = store, gen, category
        self.categories = {c["path"]: c.get("category", "") for c in gen.clips}
        self.table = gen.webs if isinstance(gen.webs, WebTable) else WebTable(gen.webs)
        # per clip, the web ids touching it in the manifest's order (CSR: ``_ids[_ptr[i]:_ptr[i+1]]``
        # for the clip ``_row`` maps to ``i``), O(webs) in numpy: no Python per web
        paths = list(dict.fromkeys([*self.categories, *self.table.strings("a")[0], *self.table.strings("b")[0]]))
        a, b = self.table.ends(paths)
        keep = np.ones(len(a), bool)
        if category is not None:
            in_cat = np.array([self.categories.get(p) == category for p in paths], bool)
            keep = in_cat[a] & in_cat[b]
        ids = np.flatnonzero(keep).astype(np.int64)
        other = ids[b[ids] != a[ids]]
        end = np.concatenate([a[ids], b[other]])
        web = np.concatenate([ids, other])
        # the order a dict filled web by web would have: by web, ``a`` before ``b``
        first = np.full(len(paths), np.iinfo(np.int64).max, np.int64)
        np.minimum.at(first, end, np.concatenate([2 * ids, 2 * other + 1]))
        order = np.lexsort((web, end))
        self._ids = web[order]
        self._scope_text: bytes | None = None  # the restriction's web keys, one a line (scope_key)
        self._ptr = np.concatenate([[0], np.cumsum(np.bincount(end, minlength=len(paths)))])
        self._row = {p: i for i, p in enumerate(paths) if self._ptr[i + 1] > self._ptr[i]}
        self._order = [paths[i] for i in np.argsort(first, kind="stable") if paths[i] in self._row]
        self.cache = cache if cache is not None else LRU()
        self.keep_webs = keep_webs
        self.reads = 0

    @classmethod
    def for_query(cls, store: MotionStore, clip: str, all_categories: bool = False,
                  generation: Generation | None = None) -> StoreWebs:
        """The webs a query on ``clip`` searches: its category's, or all with ``all_categories``."""
        gen = generation if generation is not None else load_generation(store)
        if gen is None:
            raise ValueError(f"store {store.url} was never indexed (no committed generation)")
        cats = {c["path"]: c.get("category", "") for c in gen.clips}
        if clip not in cats:
            raise ValueError(f"unknown clip {clip!r}: not in generation {gen.id} of {store.url}")
        return cls(store, gen, None if all_categories else cats[clip])

    def _load(self, rec: dict[str, Any]) -> MatchWeb:
        """Read the web of ``rec`` from the store (a StoreError naming the pair when it is missing
        or damaged)."""
        try:
            web = self.store.read_web(rec["key"], rec.get("shard"))
        except KeyError:
            raise StoreError(self.store.url, rec["key"], f"(web {rec['a']} x {rec['b']}) is missing; "
                             "run motionweb index to recompute it") from None
        except StoreError as exc:
            raise StoreError(self.store.url, rec["key"], f"(web {rec['a']} x {rec['b']}) {exc.reason}; "
                             "run motionweb index to recompute it") from None
        self.reads += 1
        return web

    def _read_many(self, recs: list[dict[str, Any]], keep: bool = True) -> dict[str, MatchWeb]:
        """The webs of ``recs`` by key: from the cache, else read in one pass in the store's order
        (``MotionStore.iter_web_arrays``: a chunk holding several of them decompressed once), a
        web that pass does not give read alone (:meth:`_load`, naming a missing or damaged one)."""
        webs, missing = {}, {}
        for rec in recs:
            web = self.cache.get(("web", rec["key"]))
            if web is None:
                missing[rec["key"]] = rec
            else:
                webs[rec["key"]] = web
        for key, web in self._read_pass(missing):
            if keep:
                self.cache.put(("web", key), web, web.nbytes)
            webs[key] = web
        return webs

    def _read_pass(self, recs: dict[str, dict[str, Any]]) -> Iterator[tuple[str, MatchWeb]]:
        """``(key, web)`` of each record of ``recs`` (by key) read from the store in one pass in
        its order (``MotionStore.iter_web_arrays``, with each record's shard), a web that pass
        does not give read alone (:meth:`_load`, naming a missing or damaged one)."""
        for key, arrays in self.store.iter_web_arrays(recs, {k: r.get("shard") for k, r in recs.items()}):
            if arrays is None:
                yield key, self._load(recs[key])
            else:
                self.reads += 1
                yield key, MatchWeb.from_arrays(arrays)

    def records_of(self, clip: str) -> list[dict[str, Any]]:
        """The manifest records of the webs touching ``clip`` in the restriction, in the
        manifest's order (KeyError: none)."""
        i = self._row.get(clip)
        if i is None:
            raise KeyError(clip)
        return [self.table[int(w)] for w in self._ids[self._ptr[i]:self._ptr[i + 1]]]

    def others_of(self, clip: str) -> list[str]:
        """The other clip of each web :meth:`__getitem__` gives for ``clip``, in its order (no
        web read; KeyError: no webs)."""
        return [r["b"] if r["a"] == clip else r["a"] for r in self.records_of(clip)]

    def content_key(self, clip: str, salt: str) -> str:
        """A hex key of what :meth:`__getitem__` gives for ``clip`` (no web read): the stored
        webs' content keys in order, each with whether it is transposed, and ``salt`` (what is
        computed from them, e.g. a packing's layout). Equal keys, equal webs: the keys name
        content (``store.keys``), so a value computed from the webs can be kept under it."""
        h = hashlib.sha256(salt.encode())
        for r in self.records_of(clip):
            h.update(f"\n{r['key']}:{int(r['a'] != clip)}".encode())
        return h.hexdigest()

    def scope_key(self, salt: str) -> str:
        """A hex key of every web of the restriction (:meth:`records`'s, by their content keys, in
        the manifest's order) and ``salt``: e.g. a quantile of their values kept under it. O(webs)
        in numpy the first time (~0.13 s for a 16,290-web category of the 381k store: the keys' text,
        then kept), O(bytes of the keys) after, no web read."""
        if self._scope_text is None:
            values, codes = self.table.strings("key")
            self._scope_text = "\n".join(values[c] for c in codes[np.unique(self._ids)]).encode()
        h = hashlib.sha256(salt.encode())
        h.update(self._scope_text)
        return h.hexdigest()

    def __getitem__(self, clip: str) -> list[tuple[str, MatchWeb]]:
        recs = self.records_of(clip)
        webs = self._read_many(recs, self.keep_webs)
        out = []
        for rec in recs:
            web = webs[rec["key"]]
            if rec["a"] == clip:
                out.append((rec["b"], web))
            else:
                t = self.cache.get(("web-t", rec["key"]))
                if t is None:
                    t = transpose(web)
                    if self.keep_webs:
                        self.cache.put(("web-t", rec["key"]), t, t.nbytes)
                out.append((rec["a"], t))
        return out

    def __iter__(self) -> Iterator[str]:
        return iter(self._order)

    def __len__(self) -> int:
        return len(self._row)

    def __contains__(self, clip: object) -> bool:
        return clip in self._row

    def records(self) -> list[dict[str, Any]]:
        """The manifest records of every web of the restriction, once each, in the manifest's order."""
        return list({r["key"]: r for r in (self.table[int(w)] for w in np.unique(self._ids))}.values())

    def all_webs(self) -> list[MatchWeb]:
        """Every web of the restriction once (e.g. for :func:`epsilon_from_quantile`), kept in
        the cache."""
        recs = self.records()
        webs = self._read_many(recs)
        return [webs[r["key"]] for r in recs]

    def map_webs(self, fn: Callable[[MatchWeb], Any], threads: int | None = None) -> list[Any]:
        """``fn(web)`` of every web of the restriction once, in :meth:`records`'s order: a web in
        the cache as it is, the others read in one pass over their shards shared among ``threads``
        threads (``MotionStore.map_web_arrays``) and not kept, a web that pass does not give read
        alone (:meth:`_load`, naming a missing or damaged one). For a pass whose answer per web is
        small (a quantile's path values); ``fn`` runs in the reading threads. O(bytes of the
        webs) / threads."""
        recs = self.records()
        out: dict[str, Any] = {}
        missing: dict[str, dict[str, Any]] = {}
        for r in recs:
            web = self.cache.get(("web", r["key"]))
            if web is not None:
                out[r["key"]] = fn(web)
            else:
                missing[r["key"]] = r
        got, alone = self.store.map_web_arrays(missing, lambda arrays: fn(MatchWeb.from_arrays(arrays)),
                                               {k: r.get("shard") for k, r in missing.items()}, threads)
        self.reads += len(got)
        out.update(got)
        for key in alone:
            out[key] = fn(self._load(missing[key]))
        return [out[r["key"]] for r in recs]
