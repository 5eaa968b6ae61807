"""Generations: manifests of complete index runs, the ``current`` pointer, garbage collection (design §9).

Layout under the store root, beside the objects of ``store/zarr_store.py``::

    generations/<id>.json                        manifest of one complete run
    current                                      JSON pointer {"generation": <id>}

A generation becomes visible only when its manifest is written and ``current`` is switched to
it (an atomic rename on local disks, a single-object put on object stores), so readers never see
a half-written index and a crashed run leaves the previous one current. The pointer records the
SHA-256 of the manifest's bytes, so a manifest damaged after its commit is found even when it
still parses. On an object store the pointer's single PUT is what makes the commit atomic: S3
replaces an object whole and reads its own writes, so a reader gets the old pointer or the new
one, and the manifest it names was written (and the objects it lists) before it (README, "On S3").

The pointer is part of the store (issue 22): :func:`check_current` tells a store that was never
indexed (no pointer, no manifest: None) from one whose pointer is missing, truncated, garbage or
names a missing generation, or whose current manifest is unreadable or differs from its checksum
(:class:`PointerError`, naming the store and the damaged file). ``motionweb verify`` reports
that; ``motionweb index`` repairs it (:func:`repair_current`). Readers (search, the app) go on
with the newest intact generation and log a warning that says to run ``motionweb index``
(:func:`current_id`): the last good index stays usable while the store waits for its repair.
:func:`gc` keeps the current generation and the ``keep - 1`` committed before it and removes
everything else: older and uncommitted manifests, temporary files of killed writes, objects no
kept manifest lists, incomplete objects and shards that serve no kept web.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import dataclass, field, fields
from importlib import metadata
from typing import Any

from motionweb.store.gcpause import gc_paused
from motionweb.store.keys import SHARDS, STORE_SCHEMA, grid_key
from motionweb.store.webtable import parse_manifest
from motionweb.store.zarr_store import MotionStore, StoreError, now_iso

log = logging.getLogger(__name__)

POINTER = "current"
#: manifest fields that differ between runs with the same content (see :func:`same_content`)
RUN_FIELDS = ("id", "created", "completed", "parent", "timings", "stats", "chunks")
PACKAGES = ("motionweb", "numpy", "scipy", "dask", "distributed", "zarr", "fsspec", "prefect", "prefect-dask")


def package_versions() -> dict[str, str]:
    """Installed versions of the packages that shape the results (recorded in each generation)."""
    out = {}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "absent"
    return out


@dataclass
class Generation:
    """The manifest of one complete index run: which content-addressed objects it includes.

    ``clips``: one record per indexed clip (path, sha256, category, frames, fps, skeleton, ...).
    ``features``: sha256 -> {rate tag: key}. ``webs``: one record per pair with keys ``a``, ``b``
    (corpus paths; ``a`` indexes the rows), ``a_sha``, ``b_sha``, ``key``, ``chunk`` and counts.
    ``broken``: files that could not be read, with the reason. ``skeleton``: per chunk, the
    majority signature and the clips indexed only against compatible ones. ``checksums``: object
    key -> SHA-256 of its bytes, for every feature object and web listed.
    """

    id: str
    created: str
    completed: str = ""
    parent: str | None = None
    store_schema: int = STORE_SCHEMA
    params: dict[str, Any] = field(default_factory=dict)
    config: dict[str, Any] = field(default_factory=dict)
    clips: list[dict[str, Any]] = field(default_factory=list)
    features: dict[str, dict[str, str]] = field(default_factory=dict)
    webs: list[dict[str, Any]] = field(default_factory=list)
    chunks: list[dict[str, Any]] = field(default_factory=list)
    broken: list[dict[str, str]] = field(default_factory=list)
    skeleton: list[dict[str, Any]] = field(default_factory=list)
    versions: dict[str, str] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    stats: dict[str, Any] = field(default_factory=dict)
    checksums: dict[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The manifest's fields, not copied (every field is JSON already: dicts, lists, scalars).
        ``dataclasses.asdict`` copied every record of them: ~4 s of the commit at 146,610 webs."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Generation:
        known = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        return cls(**known)

    def web_for(self, path_a: str, path_b: str) -> tuple[dict[str, Any], bool] | None:
        """The web record of two clips (corpus paths) and whether it is stored transposed
        (rows = ``path_b``); None when the pair is not in this generation."""
        for w in self.webs:
            if w["a"] == path_a and w["b"] == path_b:
                return w, False
            if w["a"] == path_b and w["b"] == path_a:
                return w, True
        return None


def same_content(a: Generation, b: Generation) -> bool:
    """Whether two manifests list the same content (clips, objects, checksums, config), whatever
    their ids, times, per-run counts and the shards their webs are in."""
    def content(g: Generation) -> dict[str, Any]:  # the fields as they are (no deep copy: O(webs) dicts)
        return {k: getattr(g, k) for k in g.__dataclass_fields__ if k not in RUN_FIELDS and k != "webs"}

    def record(w: dict[str, Any]) -> dict[str, Any]:  # where a web is (its shard) is not what it is
        return {k: v for k, v in w.items() if k not in ("computed", "shard")}

    return (len(a.webs) == len(b.webs) and content(a) == content(b)
            and all(record(x) == record(y) for x, y in zip(a.webs, b.webs, strict=True)))


#: how ``motionweb index`` repairs a damaged pointer or current manifest (in messages)
REPAIR = "run `motionweb index CONFIG` to repair it"


class PointerError(StoreError):
    """The store's ``current`` pointer, or the manifest it names, cannot be used.

    ``key`` is the damaged file (``current`` or ``generations/<id>.json``), ``reason`` what is
    wrong with it, ``fallback`` the newest intact generation (None: there is none) and
    ``named`` the generation the pointer names when it could be read."""

    def __init__(self, url: str, key: str, reason: str, fallback: str | None = None,
                 named: str | None = None):
        self.fallback, self.named = fallback, named
        super().__init__(url, key, reason)

    @property
    def manifest_damaged(self) -> bool:
        """True when the pointer is sound but the manifest it names is damaged."""
        return self.key != POINTER

    def __str__(self) -> str:
        after = (f"the newest intact generation is {self.fallback}" if self.fallback
                 else "no generation manifest is intact")
        return f"{super().__str__()}; {after}; {REPAIR}"


def _manifest_path(gen_id: str) -> str:
    return f"generations/{gen_id}.json"


#: per store (url): the current generation as :func:`_checked_current` last read it: (its id, its
#: manifest's SHA-256, lean, the generation). A rerun reads the current manifest three times
#: (the start, then gc's check and its list of what is live: ~4 s of the 381k store's 146,610-web
#: manifest); the bytes are still read and hashed each time, only their parse is saved
_CURRENT: dict[str, tuple[str, str, bool, Generation]] = {}


def _manifest(store: MotionStore, gen_id: str, sha256: str | None = None, lean: bool | None = False,
              remember: bool = False) -> Generation:
    """A generation's manifest, checked: it parses, names itself and was completed (and its
    bytes have the SHA-256 the pointer recorded, when given). ValueError (or OSError) saying why.
    ``lean``: see :func:`load_generation` (None: either, for a caller that needs only the checks).
    ``remember``: keep it as the store's current generation (:data:`_CURRENT`), whose same bytes
    are then not parsed again."""
    raw = store.fs.cat_file(store.path(_manifest_path(gen_id)))
    held = _CURRENT.get(store.url)
    digest = (hashlib.sha256(raw).hexdigest() if sha256 is not None or remember or (held and held[0] == gen_id)
              else None)
    if (held is not None and held[0] == gen_id and held[1] == digest and lean in (None, held[2])
            and sha256 in (None, digest)):
        return held[3]  # the same bytes, parsed and checked before
    lean = lean is None or lean  # either will do: the lean parse holds less
    try:
        with gc_paused():  # a manifest is O(webs) objects (lean: a compact table)
            if lean:
                text = raw.decode()
                del raw  # the bytes and their text are each as large as the manifest
                data = parse_manifest(text)
                del text
            else:
                data = json.loads(raw)
    except UnicodeDecodeError:
        raise ValueError("is not text (garbage bytes)") from None
    except ValueError as exc:
        raise ValueError(f"is truncated or not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"holds a JSON {type(data).__name__}, not a manifest")  # noqa: TRY004 - damage, not a caller's type error
    try:
        gen = Generation.from_dict(data)
    except TypeError as exc:
        raise ValueError(f"is not a manifest ({exc})") from None
    if gen.id != gen_id:
        raise ValueError(f"holds generation {gen.id!r}, not {gen_id!r}")
    if not gen.completed:
        raise ValueError("was never completed")
    if sha256 is not None and digest != sha256:
        raise ValueError("differs from the checksum recorded in the pointer")
    if remember:
        _CURRENT[store.url] = (gen_id, digest, lean, gen)
    return gen


def newest_intact(store: MotionStore, exclude: str | None = None) -> str | None:
    """The newest generation whose manifest reads and checks (see :func:`_manifest`), None if none.

    Any such manifest is a complete index: :func:`commit` writes a manifest only after checking
    that every object it lists is complete, and the pointer only says which one is published.
    ``exclude``: a generation not to return (a current manifest that parses but differs from
    the checksum the pointer recorded)."""
    for gid in reversed(generation_ids(store)):
        if gid == exclude:
            continue
        try:
            _manifest(store, gid, lean=True)
        except (OSError, ValueError):
            continue
        return gid
    return None


def _valid_id(value: Any) -> bool:
    return (isinstance(value, str) and bool(value) and not value.startswith(".")
            and "/" not in value and "\\" not in value and value.isprintable())


def check_current(store: MotionStore, lean: bool | None = None) -> str | None:
    """Id of the current generation, strictly: None for a store that was never indexed (no
    pointer and no manifest); :class:`PointerError` when the pointer is missing (manifests
    exist), truncated, garbage or names a missing generation, or the manifest it names is
    unreadable, incomplete or differs from the checksum the pointer recorded. ``lean``: the
    parse to keep (:func:`load_generation`; None: either), for a caller that loads the current
    generation next (:func:`current_generation` then takes it without a second parse)."""
    gen = _checked_current(store, lean=lean)
    return gen.id if gen is not None else None


def _checked_current(store: MotionStore, lean: bool | None) -> Generation | None:
    """The current generation, parsed once and checked as :func:`check_current` says (``lean``:
    see :func:`_manifest`), kept as the store's current (:data:`_CURRENT`)."""
    def damaged(key: str, reason: str, named: str | None = None) -> PointerError:
        exclude = named if key != POINTER else None
        return PointerError(store.url, key, reason, newest_intact(store, exclude), named)

    try:
        raw = store.fs.cat_file(store.path(POINTER))
    except FileNotFoundError:
        ids = generation_ids(store)
        if not ids:
            return None
        many = f"{len(ids)} manifest{'s' if len(ids) != 1 else ''}"
        raise damaged(POINTER, f"is missing (generations/ holds {many})") from None
    if not raw.strip():
        raise damaged(POINTER, "is empty (truncated)")
    try:
        data = json.loads(raw)
    except UnicodeDecodeError:
        raise damaged(POINTER, "is not text (garbage bytes)") from None
    except ValueError as exc:
        raise damaged(POINTER, f"is truncated or not valid JSON ({exc})") from None
    gid = data.get("generation") if isinstance(data, dict) else None
    if not _valid_id(gid):
        raise damaged(POINTER, f"names no generation (it holds {raw[:60]!r})")
    sha = data.get("manifest_sha256")
    try:
        return _manifest(store, gid, sha if isinstance(sha, str) else None, lean=lean, remember=True)
    except FileNotFoundError:
        raise damaged(POINTER, f"names generation {gid}, whose manifest {_manifest_path(gid)} is missing",
                      gid) from None
    except (OSError, ValueError) as exc:
        reason = f"(the manifest of current generation {gid}) {exc}"
        raise damaged(_manifest_path(gid), reason, gid) from None


#: (store url, damaged key, reason) already warned about by :func:`current_id` in this process
_WARNED: set[tuple[str, str, str]] = set()


def current_id(store: MotionStore) -> str | None:
    """Id of the current generation for readers; None for a store that was never indexed.

    When the pointer or the current manifest is damaged (:func:`check_current`), readers go on
    with the newest intact generation and log one warning per damage that names the damaged file
    and says to run ``motionweb index``: the last good index stays usable (a running ``motionweb
    app`` keeps serving) while the store waits for its repair. With no intact generation at all
    the :class:`PointerError` is raised (never "was never indexed" for a damaged store)."""
    gen = current_generation(store, lean=True)
    return gen.id if gen is not None else None


def current_generation(store: MotionStore, lean: bool = False, strict: bool = False) -> Generation | None:
    """The current generation's manifest, read and parsed once (where :func:`check_current` then
    :func:`load_generation` parse it twice: about 3 s of a 146,610-web manifest); None for a store
    that was never indexed. ``strict``: a damaged pointer or manifest raises :class:`PointerError`
    (:func:`check_current`); else it is a reader's, with :func:`current_id`'s fallback to the
    newest intact generation. ``lean``: see :func:`load_generation`."""
    try:
        return _checked_current(store, lean)
    except PointerError as exc:
        if strict or exc.fallback is None:
            raise
        if (sig := (store.url, exc.key, exc.reason)) not in _WARNED:
            _WARNED.add(sig)
            log.warning("%s: %s %s; falling back to generation %s (the newest intact one); %s",
                        store.url, exc.key, exc.reason, exc.fallback, REPAIR)
        return load_generation(store, exc.fallback, lean=lean)


def pointer_signature(store: MotionStore) -> tuple | None:
    """What changes when the current generation or its manifest may have changed: the pointer's
    bytes and the size and modification time of the manifest it names (None when either cannot
    be read). Cheap (a small read and a stat), where :func:`check_current` reads and hashes the
    whole manifest, O(webs): a long-lived reader (the service) checks strictly only when this
    changes."""
    try:
        raw = store.fs.cat_file(store.path(POINTER))
        gid = json.loads(raw).get("generation")
        if not _valid_id(gid):
            return None
        info = store.fs.info(store.path(_manifest_path(gid)))
    except (OSError, ValueError, AttributeError):
        return None
    return raw, info.get("size"), info.get("mtime", info.get("LastModified", info.get("last_modified")))


def repair_current(store: MotionStore, lean: bool | None = None) -> PointerError | None:
    """Make a damaged pointer sound again; returns the damage found (None: nothing to repair).

    The pointer is rewritten to the newest intact generation (:func:`newest_intact`), the one
    readers already fall back to, instead of waiting for the index run to commit a new one:
    the last good index is current and readable at once, a run that then fails or is killed
    leaves a sound store, and nothing is deleted (the damaged manifest is left for :func:`gc`
    after the run's next commit). When it is the current manifest that is damaged, its listing
    is lost: the caller commits a fresh generation (``motionweb index`` does, even when it lists
    the same content as the fallback) so that the store's newest generation is intact again.
    With no intact generation the pointer is left as it is and the run's commit replaces it.
    ``lean``: as for :func:`check_current`."""
    if store.read_only:
        raise PermissionError(f"{store.url}: store opened read-only")
    try:
        check_current(store, lean)
    except PointerError as exc:
        if exc.fallback is not None:
            _point_to(store, _manifest(store, exc.fallback))
        return exc
    return None


def _point_to(store: MotionStore, gen: Generation) -> str:
    """Switch ``current`` to a written manifest, recording the SHA-256 of its bytes (returned)."""
    raw = store.fs.cat_file(store.path(_manifest_path(gen.id)))
    digest = hashlib.sha256(raw).hexdigest()
    store.write_json(POINTER, {"generation": gen.id, "committed": gen.completed, "manifest_sha256": digest})
    return digest


def load_generation(store: MotionStore, gen_id: str | None = None, lean: bool = False) -> Generation | None:
    """A generation's manifest (the current one by default, see :func:`current_id`); None when
    the store was never indexed. ``lean`` (a reader that searches, e.g. the app): the web records
    parsed one at a time into a :class:`~motionweb.store.webtable.WebTable` (a 146,610-web
    manifest: ~50 MB of columns instead of ~300 MB of dicts, which a process does not give back
    once it held them) and the object checksums left out (they serve verification and the index,
    which load the manifest whole)."""
    gen_id = gen_id or current_id(store)
    if gen_id is None:
        return None
    try:
        return _manifest(store, gen_id, lean=lean)
    except (OSError, ValueError) as exc:
        raise StoreError(store.url, _manifest_path(gen_id), str(exc) if isinstance(exc, ValueError)
                         else f"is unreadable ({type(exc).__name__})") from None


def generation_ids(store: MotionStore) -> list[str]:
    """Manifests in the store, oldest first (ids sort by time)."""
    try:
        names = store.fs.ls(store.path("generations"), detail=False)
    except FileNotFoundError:
        return []
    return sorted(os.path.basename(n)[:-5] for n in names if n.endswith(".json"))


@dataclass(frozen=True)
class Problem:
    """One object of a generation that cannot be used: what it is (clip or web), key, reason."""

    what: str
    key: str
    reason: str

    def __str__(self) -> str:
        return f"{self.what} ({self.key}): {self.reason}"


def verify_generation(store: MotionStore, gen: Generation) -> list[Problem]:
    """Every feature object and web a generation lists, read whole and checked against the
    checksums recorded with it and in the manifest. Cost: one read of the generation's objects."""
    clip_of = {c["sha256"]: c["path"] for c in gen.clips}
    problems = []
    for sha, rates in sorted(gen.features.items()):
        for key in sorted(set(rates.values())):
            if (reason := store.verify(key, gen.checksums.get(key))) is not None:
                problems.append(Problem(f"features of {clip_of.get(sha, sha[:12])}", key, reason))
    for w in gen.webs:
        if (reason := store.verify(w["key"], gen.checksums.get(w["key"]))) is not None:
            problems.append(Problem(f"web {w['a']} x {w['b']}", w["key"], reason))
    return problems


def commit(store: MotionStore, gen: Generation) -> str:
    """Publish a generation: write its manifest, then switch ``current`` to it.

    Every object it lists must already be complete (checked); until the pointer moves the
    previous generation stays current.
    """
    if store.read_only:
        raise PermissionError(f"{store.url}: store opened read-only")
    missing = [w["key"] for w in gen.webs if not store.has(w["key"])]
    missing += [k for rates in gen.features.values() for k in set(rates.values()) if not store.has(k)]
    if missing:
        raise RuntimeError(f"refusing to commit generation {gen.id}: {len(missing)} objects missing, "
                           f"e.g. {missing[0]}")
    store.ensure_root()
    gen.completed = gen.completed or now_iso()
    store.write_json(_manifest_path(gen.id), gen.to_dict())
    digest = _point_to(store, gen)
    # the store's current generation is the one in hand: gc's check of the pointer right after
    # (and a rerun's) hashes the manifest's bytes but does not parse them again (~3 s at 146,610 webs)
    _CURRENT[store.url] = (gen.id, digest, False, gen)
    return gen.id


def gc(store: MotionStore, keep: int = 3) -> list[str]:
    """Remove what no kept generation needs; returns the removed keys (objects and files).

    Kept: the current generation and the ``keep - 1`` manifests committed before it. Removed:
    other manifests (older ones, and uncommitted ones newer than the current), ``*.tmp-*`` files
    of killed writes, feature and grid objects no kept manifest lists (or left incomplete), and
    shards that serve no kept web (orphans of killed runs, superseded or damaged shards). The
    older kept manifests are read only when the store holds an object or shard the current one
    does not list (a nightly run that only added webs reads none; a damaged one is then dropped
    from the kept, as when it is read). Never
    run it concurrently with an index run (``motionweb index`` runs it after its commit). A store
    whose pointer or current manifest is damaged is not touched (:class:`PointerError`): which
    generations are committed is unknown until ``motionweb index`` repairs it.
    """
    if keep < 1:
        raise ValueError(f"gc keeps at least the current generation (keep={keep})")
    ids = generation_ids(store)
    cur = check_current(store)
    if cur is None:
        return []
    committed = [i for i in ids if i <= cur]
    kept = set(committed[-keep:]) | {cur}
    live: set[str] = set()

    def keep_listed(gids: list[str]) -> None:
        for gid in gids:
            try:
                g = _manifest(store, gid)
            except (OSError, ValueError):
                kept.discard(gid)
                continue
            live.update(w["key"] for w in g.webs)
            live.update(grid_key(w["key"]) for w in g.webs)
            live.update(k for rates in g.features.values() for k in rates.values())

    def serving_live() -> set[str | None]:
        return {store.web_shard(k) for k in live if k.startswith("webs/")}

    keep_listed([cur])  # held after a commit (no parse then)
    objects = [key for top, depth in (("features", 3), ("grids", 3)) for key in store.leaf_keys(top, depth)]
    shards = store.leaf_keys(SHARDS, 2)
    serving = serving_live()
    if any(k not in live for k in objects) or any(s not in serving for s in shards):
        # only an object the current generation does not list can be one an older kept generation
        # needs: their manifests (~1–2 s of parse each at 146,610 webs) are read only then
        keep_listed(sorted(kept - {cur}))
        serving = serving_live()
    removed: list[str] = []
    for key in objects:
        if key not in live or not store.has(key):
            store.delete(key)
            removed.append(key)
    for shard in shards:
        if shard not in serving:
            store.delete(shard)
            removed.append(shard)
    for gid in set(ids) - kept:
        store.fs.rm(store.path(f"generations/{gid}.json"))
        removed.append(f"generations/{gid}.json")
    for folder in ("", "generations"):
        try:
            names = store.fs.ls(store.path(folder) if folder else store.root, detail=False)
        except FileNotFoundError:
            continue
        for name in names:
            if ".tmp-" in os.path.basename(name):
                store.fs.rm(name)
                removed.append(f"{folder}/{os.path.basename(name)}".lstrip("/"))
    return removed
