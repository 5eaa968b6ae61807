"""Corpus catalog: labels (folders, rules, manifest), hashes, clip facts and broken files."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from fixtures import tiny_motion
from motionweb.store.bvh import write_bvh
from motionweb.store.catalog import CategoryRule, CorpusParams, load_clip, scan_corpus


@pytest.fixture
def corpus(tmp_path: Path) -> Path:
    root = tmp_path / "corpus"
    (root / "walk").mkdir(parents=True)
    (root / "jump" / "deep").mkdir(parents=True)
    write_bvh(tiny_motion(30, 30.0), root / "walk" / "w1.bvh")
    write_bvh(tiny_motion(120, 120.0, ("hips", "knee", "ankle")), root / "jump" / "deep" / "j1.bvh")
    write_bvh(tiny_motion(10, 60.0), root / "loose.bvh")
    (root / "walk" / "broken.bvh").write_text("HIERARCHY\nROOT a\n{\n")
    (root / "walk" / "notes.md").write_text("not a clip")
    return root


def test_scan_labels_hashes_and_facts(corpus: Path) -> None:
    cat = scan_corpus(corpus)
    assert [e.path for e in cat.entries] == ["jump/deep/j1.bvh", "loose.bvh", "walk/w1.bvh"]
    by = {e.path: e for e in cat.entries}
    assert by["walk/w1.bvh"].category == "walk"
    assert by["jump/deep/j1.bvh"].category == "jump"
    assert by["loose.bvh"].category == "uncategorized"
    j = by["jump/deep/j1.bvh"]
    assert (j.frames, j.fps, j.n_joints) == (120, 120.0, 3)
    assert j.duration == pytest.approx(119 / 120)
    assert j.sha256 == hashlib.sha256((corpus / j.path).read_bytes()).hexdigest()
    assert by["walk/w1.bvh"].skeleton == by["loose.bvh"].skeleton != j.skeleton
    assert set(cat.by_category()) == {"jump", "uncategorized", "walk"}


@pytest.mark.parametrize("threads", [2, 5])
def test_the_catalog_is_the_same_whatever_the_threads(corpus: Path, threads: int) -> None:
    """Files read by several threads give the one-thread catalog: entries and errors in file order."""
    for i in range(12):  # more files than threads, broken ones among them
        if i % 4 == 3:
            (corpus / "walk" / f"bad{i:02d}.bvh").write_text("HIERARCHY\nROOT a\n{\n")
        else:
            write_bvh(tiny_motion(5 + i, 30.0), corpus / "walk" / f"x{i:02d}.bvh")
    one = scan_corpus(corpus, threads=1)
    assert len(one.entries) == 12 and len(one.errors) == 4
    assert scan_corpus(corpus, threads=threads).to_dict() == one.to_dict()


def test_broken_file_is_reported_and_skipped(corpus: Path) -> None:
    cat = scan_corpus(corpus)
    assert [e.path for e in cat.errors] == ["walk/broken.bvh"]
    assert "broken.bvh" in cat.errors[0].reason and "no MOTION section" in cat.errors[0].reason


def test_rules_and_manifest(corpus: Path, tmp_path: Path) -> None:
    rules = CorpusParams(category_rules=[CategoryRule(pattern=r"^loose", category="idle")])
    assert {e.path: e.category for e in scan_corpus(corpus, rules).entries}["loose.bvh"] == "idle"
    manifest = tmp_path / "m.csv"
    manifest.write_text("path,category\nwalk/w1.bvh,locomotion\n")
    cfg = CorpusParams(manifest=str(manifest), category_rules=[CategoryRule(pattern="w1", category="x")])
    assert {e.path: e.category for e in scan_corpus(corpus, cfg).entries}["walk/w1.bvh"] == "locomotion"
    bad = tmp_path / "bad.csv"
    bad.write_text("file,label\n")
    with pytest.raises(ValueError, match="bad.csv"):
        scan_corpus(corpus, CorpusParams(manifest=str(bad)))


def test_load_clip_and_change_detection(corpus: Path) -> None:
    cat = scan_corpus(corpus, CorpusParams(length_unit="cm"))
    entry = cat.find("w1")
    m = load_clip(entry, CorpusParams(length_unit="cm"))
    assert m.n_frames == 30 and m.scale_to_m == 0.01
    (corpus / "walk" / "w1.bvh").write_text((corpus / "walk" / "w1.bvh").read_text() + "\n\n")
    with pytest.raises(ValueError, match="changed since"):
        load_clip(entry, CorpusParams())
    with pytest.raises(KeyError, match="nope"):
        cat.find("nope")


def test_unchanged_clips_described_before_are_not_parsed_again(corpus: Path, monkeypatch) -> None:
    """A scan given the records of an earlier one (``known``, as a generation lists its clips)
    describes each BVH whose bytes are unchanged from its record, without parsing it: the same
    catalog as a full scan. A changed file, one whose sidecar now gives another unit, a record
    for another path, and a broken file are read as before; a sidecar that keeps the unit is
    read, not the clip."""
    import json
    from dataclasses import asdict

    import motionweb.store.catalog as catalog

    full = scan_corpus(corpus)
    known = {e.path: {k: v for k, v in asdict(e).items() if k != "abs_path"} | {"chunk": e.category}
             for e in full.entries}
    parsed: list[str] = []
    real = catalog.read_motion

    def counting(path, **kw):
        parsed.append(Path(path).name)
        return real(path, **kw)

    monkeypatch.setattr(catalog, "read_motion", counting)
    assert scan_corpus(corpus, known=known).to_dict() == full.to_dict()
    assert parsed == ["broken.bvh"]

    (corpus / "walk" / "w1.json").write_text(json.dumps({"actions": [], "unit": known["walk/w1.bvh"]["unit"]}))
    parsed.clear()
    assert scan_corpus(corpus, known=known).to_dict() == full.to_dict() and parsed == ["broken.bvh"]
    write_bvh(tiny_motion(40, 30.0), corpus / "walk" / "w1.bvh")  # changed: 40 frames now
    (corpus / "loose.json").write_text(json.dumps({"unit": "cm"}))  # a sidecar beside loose.bvh
    known["walk/w2.bvh"] = known["jump/deep/j1.bvh"]  # a record for another path's bytes
    write_bvh(tiny_motion(30, 30.0), corpus / "walk" / "w2.bvh")
    parsed.clear()
    again = scan_corpus(corpus, known=known)
    monkeypatch.undo()
    assert sorted(parsed) == ["broken.bvh", "loose.bvh", "w1.bvh", "w2.bvh"]
    assert again.to_dict() == scan_corpus(corpus).to_dict()
    by = {e.path: e for e in again.entries}
    assert by["walk/w1.bvh"].frames == 40 and by["loose.bvh"].unit == "cm"
