"""Generations (design §9): pointer semantics, crashes, commit checks, gc."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fixtures import ragged_web
from motionweb.store import generations
from motionweb.store.generations import (
    Generation,
    PointerError,
    check_current,
    commit,
    current_generation,
    current_id,
    gc,
    generation_ids,
    load_generation,
    pointer_signature,
    repair_current,
)
from motionweb.store.keys import web_key
from motionweb.store.zarr_store import MotionStore, new_id, now_iso

SHA_A = "a" * 64
SHA_B = "b" * 64


def _gen(store: MotionStore, webs: list[str]) -> Generation:
    return Generation(id=new_id(), created=now_iso(),
                      webs=[{"a": f"x{i}", "b": f"y{i}", "key": k} for i, k in enumerate(webs)])


def test_generation_pointer_and_crash(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    assert current_id(store) is None and load_generation(store) is None
    k1 = web_key(SHA_A, SHA_A, "wd1")
    store.write_web(k1, ragged_web(np.random.default_rng(3)))
    g1 = _gen(store, [k1])
    commit(store, g1)
    assert current_id(store) == g1.id

    # a second run writes a new object then "crashes" before committing
    k2 = web_key(SHA_A, SHA_B, "wd1")

    def crashing_run():
        store.write_web(k2, ragged_web(np.random.default_rng(4)))
        raise RuntimeError("worker lost")

    with pytest.raises(RuntimeError):
        crashing_run()
    reader = MotionStore(str(tmp_path / "s"), read_only=True)
    assert current_id(reader) == g1.id
    assert [w["key"] for w in load_generation(reader).webs] == [k1]
    reader.read_web_arrays(k1)  # still readable
    # the next run resumes: the complete object from the crashed run is reused as cached
    assert store.has(k2)
    g2 = _gen(store, [k1, k2])
    g2.parent = g1.id
    commit(store, g2)
    assert current_id(store) == g2.id and generation_ids(store) == sorted([g1.id, g2.id])
    assert load_generation(store, g1.id).webs == g1.webs  # old generations stay readable
    with pytest.raises(PermissionError):
        commit(reader, _gen(reader, []))


def test_commit_refuses_missing_objects(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    with pytest.raises(RuntimeError, match="missing"):
        commit(store, _gen(store, [web_key(SHA_A, SHA_B, "nope")]))
    assert current_id(store) is None


def test_pointer_is_atomic_json(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    g = _gen(store, [])
    commit(store, g)
    data = json.loads((tmp_path / "s" / "current").read_text())
    assert data["generation"] == g.id
    assert not list((tmp_path / "s").glob("current.tmp-*"))


def test_gc_keeps_listed_objects(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    rng = np.random.default_rng(5)
    k_old = web_key(SHA_A, SHA_B, "wd0")
    k_new = web_key(SHA_A, SHA_B, "wd1")
    store.write_web(k_old, ragged_web(rng))
    commit(store, _gen(store, [k_old]))
    store.write_web(k_new, ragged_web(rng))
    commit(store, _gen(store, [k_new]))
    removed = gc(store, keep=1)
    assert any(r.startswith("webs/shards/wd0/") for r in removed) and len(removed) == 2  # shard + manifest
    assert store.has(k_new) and not store.has(k_old)
    assert len(generation_ids(store)) == 1


def test_gc_reads_older_kept_manifests_only_for_objects_the_current_one_does_not_list(tmp_path, monkeypatch):
    """An object only an older kept generation lists is kept (its manifest read for it); with none,
    gc reads the current manifest alone (a nightly run that only added webs)."""
    store = MotionStore(str(tmp_path / "s"))
    rng = np.random.default_rng(7)
    k_old, k_new = web_key(SHA_A, SHA_B, "wd0"), web_key(SHA_A, SHA_B, "wd1")
    store.write_web(k_old, ragged_web(rng))
    g1 = _gen(store, [k_old])
    commit(store, g1)
    store.write_web(k_new, ragged_web(rng))
    g2 = _gen(store, [k_new])
    commit(store, g2)
    monkeypatch.setattr(generations, "_CURRENT", {})  # a new process: every manifest read is a parse
    parsed: list[str] = []
    real = Generation.from_dict
    monkeypatch.setattr(Generation, "from_dict", staticmethod(lambda data: parsed.append(data.get("id")) or real(data)))
    assert gc(store, keep=2) == []
    assert g1.id in parsed and store.has(k_old) and store.has(k_new)
    g3 = _gen(store, [k_old, k_new])  # lists both: nothing in the store the current does not list
    commit(store, g3)
    parsed.clear()
    assert gc(store, keep=2) == [f"generations/{g1.id}.json"]  # kept: g2 and g3
    assert parsed == []  # g3 is held after its commit; g2 is not read
    assert gc(store, keep=1) == [f"generations/{g2.id}.json"]
    assert store.has(k_old) and store.has(k_new)


def test_an_index_runs_check_parses_the_manifest_it_then_loads(tmp_path, monkeypatch):
    """The index flow checks the pointer (repair_current) asking for the whole parse, which
    current_generation then takes: one parse of the current manifest, not a lean one and a whole one."""
    store, _, g2 = _two_generations(tmp_path)
    monkeypatch.setattr(generations, "_CURRENT", {})  # a new process
    parsed: list[str] = []
    real = Generation.from_dict
    monkeypatch.setattr(Generation, "from_dict", staticmethod(lambda data: parsed.append(data.get("id")) or real(data)))
    lean_parses: list[int] = []
    real_lean = generations.parse_manifest
    monkeypatch.setattr(generations, "parse_manifest", lambda *a, **k: lean_parses.append(1) or real_lean(*a, **k))
    assert repair_current(store, lean=False) is None
    gen = current_generation(store, strict=True)
    assert gen.id == g2.id and parsed == [g2.id] and lean_parses == []


def test_gc_removes_leftovers_of_killed_runs(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    rng = np.random.default_rng(6)
    k = web_key(SHA_A, SHA_B, "wd1")
    store.write_web(k, ragged_web(rng))
    g = _gen(store, [k])
    commit(store, g)
    store.write_web(web_key(SHA_B, SHA_B, "wd1"), ragged_web(rng))  # written, never committed
    store.write_webs([(k, ragged_web(rng), {})])  # a newer shard now serves k; the old one is superseded
    (tmp_path / "s" / "current.tmp-0dead").write_text("{")
    (tmp_path / "s" / "generations" / "99991231T000000000000Z-0dead0.json").write_text("{}")  # uncommitted
    removed = gc(store, keep=3)
    assert "current.tmp-0dead" in removed and "generations/99991231T000000000000Z-0dead0.json" in removed
    fresh = MotionStore(str(tmp_path / "s"))
    assert fresh.has(k) and not fresh.has(web_key(SHA_B, SHA_B, "wd1"))
    assert len(fresh.leaf_keys("webs/shards", 2)) == 1 and current_id(fresh) == g.id


def _two_generations(tmp_path) -> tuple[MotionStore, Generation, Generation]:
    store = MotionStore(str(tmp_path / "s"))
    g1, g2 = _gen(store, []), _gen(store, [])
    commit(store, g1)
    commit(store, g2)
    return store, g1, g2


def _damage(tmp_path, kind: str, g2: Generation) -> str:
    """Damage the store of :func:`_two_generations`; returns the damaged file's key."""
    root = tmp_path / "s"
    pointer, manifest = root / "current", root / "generations" / f"{g2.id}.json"
    if kind == "truncated pointer":
        pointer.write_text(pointer.read_text()[:20])
    elif kind == "empty pointer":
        pointer.write_text("")
    elif kind == "deleted pointer":
        pointer.unlink()
    elif kind == "garbage pointer":
        pointer.write_bytes(b"\x00\xff\x13garbage")
    elif kind == "pointer without id":
        pointer.write_text('{"generation": "../../etc/passwd"}')
    elif kind == "pointer to a missing generation":
        pointer.write_text(json.dumps({"generation": "20990101T000000000000Z-000000"}))
    elif kind == "truncated manifest":
        manifest.write_text(manifest.read_text()[:30])
        return f"generations/{g2.id}.json"
    elif kind == "edited manifest":  # still parses: found by the checksum the pointer recorded
        manifest.write_text(manifest.read_text().replace('"clips": []', '"clips": [{"path": "x"}]'))
        return f"generations/{g2.id}.json"
    return "current"


POINTER_DAMAGE = ["truncated pointer", "empty pointer", "deleted pointer", "garbage pointer",
                  "pointer without id", "pointer to a missing generation"]
MANIFEST_DAMAGE = ["truncated manifest", "edited manifest"]


@pytest.mark.parametrize("kind", POINTER_DAMAGE + MANIFEST_DAMAGE)
def test_damaged_pointer_is_reported_read_around_and_repaired(tmp_path, caplog, kind):
    store, g1, g2 = _two_generations(tmp_path)
    assert check_current(store) == g2.id and repair_current(store) is None
    key = _damage(tmp_path, kind, g2)
    with pytest.raises(PointerError) as info:
        check_current(store)
    err = info.value
    assert err.key == key and str(tmp_path / "s") in str(err) and f"object {key} " in str(err)
    assert "motionweb index" in str(err) and "Traceback" not in str(err)
    fallback = g1.id if key != "current" else g2.id
    assert err.fallback == fallback and err.manifest_damaged == (key != "current")
    # readers go on with the newest intact generation, with one warning naming the damage
    assert current_id(store) == fallback and load_generation(store).id == fallback
    assert f"falling back to generation {fallback}" in caplog.text and key in caplog.text
    caplog.clear()
    current_id(store)
    assert not caplog.text  # once per damage, not per request
    with pytest.raises(PointerError):
        gc(store)  # which generations are committed is unknown: nothing is removed
    assert generation_ids(store) == [g1.id, g2.id]
    # the repair: the pointer names the newest intact generation again
    found = repair_current(store)
    assert found is not None and found.key == key
    assert check_current(store) == fallback and repair_current(store) is None
    assert (tmp_path / "s" / f"generations/{g2.id}.json").exists()  # the repair deletes nothing


def _count_parses(monkeypatch) -> list[str]:
    """The generation ids whose manifest is parsed from now on."""
    seen, parse = [], generations._manifest

    def counting(store, gen_id, *args, **kwargs):
        seen.append(gen_id)
        return parse(store, gen_id, *args, **kwargs)

    monkeypatch.setattr(generations, "_manifest", counting)
    return seen


@pytest.mark.parametrize("lean", [False, True])
def test_current_generation_parses_the_manifest_once(tmp_path, monkeypatch, lean):
    store, _, _ = _two_generations(tmp_path)
    keys = [web_key(SHA_A, SHA_B, "wd1"), web_key(SHA_B, SHA_B, "wd1")]
    for i, k in enumerate(keys):
        store.write_web(k, ragged_web(np.random.default_rng(i)))
    g3 = _gen(store, keys)
    commit(store, g3)
    monkeypatch.setattr(generations, "_CURRENT", {})  # another process: nothing held from the commit
    parsed = _count_parses(monkeypatch)
    gen = current_generation(store, lean=lean, strict=True)
    assert parsed == [g3.id] and gen.id == g3.id
    webs = [{k: w[k] for k in ("a", "b", "key")} for w in gen.to_dict()["webs"]]
    assert webs == [{k: w[k] for k in ("a", "b", "key")} for w in g3.webs] and len(webs) == 2
    assert current_generation(MotionStore(str(tmp_path / "empty"))) is None


def test_a_commit_leaves_its_generation_current_unparsed(tmp_path, monkeypatch):
    """After a commit, gc's check of the pointer and its list of what is live take the generation
    in hand (the bytes are still read and hashed): no parse of the manifest just written, and
    what is held equals that manifest parsed. Damage after the commit is still found."""
    store, _, _ = _two_generations(tmp_path)
    keys = [web_key(SHA_A, SHA_B, "wd1")]
    store.write_web(keys[0], ragged_web(np.random.default_rng(5)))
    g3 = _gen(store, keys)
    parsed: list[str] = []
    real = Generation.from_dict
    monkeypatch.setattr(Generation, "from_dict", staticmethod(lambda data: parsed.append(data.get("id")) or real(data)))
    commit(store, g3)
    assert check_current(store) == g3.id
    gc(store)
    assert g3.id not in parsed
    held = current_generation(store, strict=True)
    assert held.to_dict() == json.loads((tmp_path / "s" / "generations" / f"{g3.id}.json").read_text())
    _damage(tmp_path, "edited manifest", g3)
    with pytest.raises(PointerError, match="differs from the checksum"):
        check_current(store)


def test_the_current_manifest_is_parsed_once_per_run_unless_its_bytes_change(tmp_path, monkeypatch):
    """A rerun reads the current manifest at its start, then gc checks it and lists what it keeps:
    the same bytes are parsed once (each read still hashed); the other kept manifests are not
    parsed when the store holds nothing the current one does not list, and the current one is
    parsed again once its bytes differ (an edit is then damage the pointer's checksum finds)."""
    store, g1, g2 = _two_generations(tmp_path)
    monkeypatch.setattr(generations, "_CURRENT", {})  # a rerun: a new process holds nothing yet
    parsed: list[str] = []
    real = Generation.from_dict

    def counting(data):
        parsed.append(data.get("id"))
        return real(data)

    monkeypatch.setattr(Generation, "from_dict", staticmethod(counting))
    assert current_generation(store, strict=True).id == g2.id
    assert check_current(store) == g2.id
    assert gc(store) == []
    assert parsed == [g2.id]
    _damage(tmp_path, "edited manifest", g2)
    with pytest.raises(PointerError, match="differs from the checksum"):
        check_current(store)
    assert parsed.count(g2.id) == 2


@pytest.mark.parametrize("kind", ["truncated pointer", "edited manifest"])
def test_current_generation_strict_raises_reader_falls_back(tmp_path, caplog, kind):
    store, g1, g2 = _two_generations(tmp_path)
    key = _damage(tmp_path, kind, g2)
    with pytest.raises(PointerError) as info:
        current_generation(store, strict=True)
    assert info.value.key == key
    fallback = g1.id if key != "current" else g2.id
    assert current_generation(store, lean=True).id == fallback
    assert f"falling back to generation {fallback}" in caplog.text


def test_never_indexed_is_not_damage(tmp_path):
    store = MotionStore(str(tmp_path / "s"))
    assert check_current(store) is None and current_id(store) is None and repair_current(store) is None
    (tmp_path / "s" / "generations").mkdir()
    assert check_current(store) is None  # an empty generations/ folder


@pytest.mark.parametrize("kind", ["deleted pointer", "truncated manifest"])
def test_no_intact_generation_is_damage_not_never_indexed(tmp_path, kind):
    store = MotionStore(str(tmp_path / "s"))
    g = _gen(store, [])
    commit(store, g)
    manifest = tmp_path / "s" / "generations" / f"{g.id}.json"
    manifest.write_text(manifest.read_text()[:30])
    if kind == "deleted pointer":
        (tmp_path / "s" / "current").unlink()
    with pytest.raises(PointerError, match="no generation manifest is intact") as info:
        current_id(store)  # readers too: not "was never indexed"
    assert info.value.fallback is None
    assert repair_current(store) is not None
    with pytest.raises(PointerError):  # left for the index run's commit
        check_current(store)
    g2 = _gen(store, [])
    commit(store, g2)
    assert check_current(store) == g2.id


def test_verify_generation_names_clip_and_web(tmp_path):
    from motionweb.store.generations import verify_generation

    store = MotionStore(str(tmp_path / "s"))
    k = web_key(SHA_A, SHA_B, "wd1")
    store.write_web(k, ragged_web(np.random.default_rng(7)))
    g = _gen(store, [k])
    g.checksums = {k: store.recorded_checksum(k)}
    commit(store, g)
    assert verify_generation(store, g) == []
    g.checksums[k] = "0" * 64
    (problem,) = verify_generation(store, g)
    assert problem.what == "web x0 x y0" and problem.key == k and "manifest" in problem.reason


@pytest.mark.parametrize("kind", POINTER_DAMAGE + MANIFEST_DAMAGE)
def test_pointer_signature_changes_with_any_damage_or_commit(tmp_path, kind):
    """The service checks the pointer strictly only when this signature changes: it must change
    with every commit and with every damage a strict check finds (none of them keeps it)."""
    import os
    import time

    store, _, g2 = _two_generations(tmp_path)
    before = pointer_signature(store)
    assert before is not None and pointer_signature(store) == before
    manifest = tmp_path / "s" / "generations" / f"{g2.id}.json"
    stat = manifest.stat()
    _damage(tmp_path, kind, g2)
    if manifest.exists() and kind in MANIFEST_DAMAGE:  # even a rewrite within the same clock tick
        os.utime(manifest, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert pointer_signature(store) != before
    store, _, _ = _two_generations(tmp_path / "again")
    before = pointer_signature(store)
    time.sleep(0.01)
    commit(store, _gen(store, []))
    assert pointer_signature(store) != before
