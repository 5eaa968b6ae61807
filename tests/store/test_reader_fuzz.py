"""Seeded mutation fuzzing of every reader through ``read_motion`` (issue: hostile files).

Each mutant of a valid file (token swaps for hostile values, deletions, duplications, swaps of
lines, truncation, inserted bytes, numbers scaled by powers of ten, bit flips, deep nesting) must
either parse into a motion whose numbers are finite, with unit quaternions and a sane frame rate,
or raise a :class:`MotionFormatError` naming the file. The catch-all :class:`ReaderFailure` of
``read_motion`` counts as a failure: it means a reader let a foreign exception through.
"""

from __future__ import annotations

import random
import re
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from fixtures import CHAIN_AMC, CHAIN_ASF, deepmimic_frame, handmade_urdf_text, wiggle
from motionweb.store.bvh import format_bvh
from motionweb.store.catalog import scan_corpus
from motionweb.store.deepmimic import read_humanoid_urdf
from motionweb.store.errors import MotionFormatError, ReaderFailure
from motionweb.store.formats import read_motion

MUTANTS = 1000

HOSTILE = ["1e999", "-1e999", "nan", "inf", "-inf", "1e-320", "1e308", "0", "-0", "-1", "1_000", "0x1F",
           "99999999999999999999", "4" * 400, "", "{", "}", "[", "]", ",", ":", '"', "true", "null", "#",
           "JOINT", "ROOT", "End", "Site", "OFFSET", "CHANNELS", "7", "Xrotation", "Xposition", "MOTION",
           "Frames:", "Frame Time:", "begin", "end", "root", "dof", "limits", ":bonedata", ":hierarchy",
           ":root", "length", "rx", "l", "<", ">", "/>", "<!ENTITY a 'b'>", "&amp;", "<mesh/>",
           "\ufeff", "\t", "\f", "\u2028", "\r", "\x00", "\xe9", "é"]
INSERTS = ["\ufeff", "\t", "\f", "\v", "\u2028", "\u0085", "\r", "\r\n", "\n", "\x00", " ", "\n\n", "#"]
NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e-?\d+)?")


def mutate(text: str, rng: random.Random) -> str:
    """One to three random edits of ``text``."""
    for _ in range(rng.randint(1, 3)):
        op = rng.randrange(10)
        n = len(text)
        i = rng.randrange(n + 1)
        if op == 0:  # a token replaced by a hostile value
            toks = list(re.finditer(r"\S+", text))
            if toks:
                m = rng.choice(toks)
                text = text[:m.start()] + rng.choice(HOSTILE) + text[m.end():]
        elif op == 1:  # delete a span
            text = text[:i] + text[i + rng.randint(1, 60):]
        elif op == 2:  # duplicate a line
            lines = text.split("\n")
            k = rng.randrange(len(lines))
            lines.insert(k, lines[k])
            text = "\n".join(lines)
        elif op == 3:  # swap two lines
            lines = text.split("\n")
            a, b = rng.randrange(len(lines)), rng.randrange(len(lines))
            lines[a], lines[b] = lines[b], lines[a]
            text = "\n".join(lines)
        elif op == 4:  # truncate
            text = text[:i]
        elif op == 5:  # insert white space, line breaks, NUL, BOM
            text = text[:i] + rng.choice(INSERTS) + text[i:]
        elif op == 6:  # a number scaled by a power of ten or negated
            nums = list(NUMBER.finditer(text))
            if nums:
                m = rng.choice(nums)
                scaled = f"{m.group()}e{rng.randint(-330, 330)}" if "e" not in m.group() else m.group()
                text = text[:m.start()] + rng.choice(["-" + m.group(), scaled]) + text[m.end():]
        elif op == 7:  # flip a bit
            if n:
                k = rng.randrange(n)
                text = text[:k] + chr((ord(text[k]) ^ (1 << rng.randrange(7))) or 1) + text[k + 1:]
        elif op == 8:  # deep nesting
            piece = rng.choice(["JOINT j {\n OFFSET 0 0 0\n", "[", "{\"a\":", "<link>", "begin\n"])
            text = text[:i] + piece * rng.choice([10, 1200]) + text[i:]
        else:  # a line repeated many times (big declared or real sizes)
            lines = text.split("\n")
            k = rng.randrange(len(lines))
            lines[k:k] = [lines[k]] * rng.choice([2, 50])
            text = "\n".join(lines)
    return text


def check(path: Path, outcomes: Counter, failures: list[str]) -> None:
    """Read one mutant: a sane motion or a MotionFormatError naming the file; anything else fails."""
    try:
        m = read_motion(path)
    except ReaderFailure as exc:
        failures.append(f"{path.name}: {exc}")
        return
    except MotionFormatError as exc:
        if str(path) not in str(exc) and exc.path is None:
            failures.append(f"{path.name}: error names no file: {exc}")
        outcomes[type(exc).__name__] += 1
        outcomes["with line"] += exc.line is not None
        return
    except Exception as exc:  # noqa: BLE001 - the point of the test
        failures.append(f"{path.name}: {type(exc).__name__}: {exc}")
        return
    norms = np.linalg.norm(m.rotations, axis=-1)
    sane = (np.isfinite(m.root_positions).all() and np.isfinite(m.rotations).all()
            and np.allclose(norms, 1.0, atol=1e-6) and np.isfinite(m.skeleton.offsets).all()
            and 1e-1 <= m.fps <= 1e5 and m.n_frames > 0
            and all(np.isfinite(t).all() for t in m.translations.values()))
    if not sane:
        failures.append(f"{path.name}: parsed into a motion with non-finite or absurd values")
    outcomes["parsed"] += 1


def run(write_mutant, seed: int) -> tuple[Counter, list[str], float]:
    rng = random.Random(seed)
    outcomes: Counter = Counter()
    failures: list[str] = []
    t0 = time.perf_counter()
    for k in range(MUTANTS):
        check(write_mutant(k, rng), outcomes, failures)
    return outcomes, failures, time.perf_counter() - t0


def report(outcomes: Counter, failures: list[str]) -> str:
    return f"{len(failures)} failures of {MUTANTS}, e.g. {failures[:5]}; outcomes {dict(outcomes)}"


def test_bvh_mutants(tmp_path: Path) -> None:
    seed = format_bvh(wiggle(12, 30.0, seed=1), decimals=4)

    def write(k: int, rng: random.Random) -> Path:
        p = tmp_path / f"m{k}.bvh"
        p.write_text(mutate(seed, rng), encoding="utf-8", errors="surrogatepass")
        return p

    outcomes, failures, _ = run(write, seed=14)
    assert not failures, report(outcomes, failures)
    assert outcomes["parsed"] > 20 and sum(v for k, v in outcomes.items() if k.endswith("Error")) > 200, outcomes


def test_asfamc_mutants(tmp_path: Path) -> None:
    def write(k: int, rng: random.Random) -> Path:
        folder = tmp_path / f"m{k}"
        folder.mkdir()
        asf, amc = CHAIN_ASF, CHAIN_AMC * 1
        if rng.random() < 0.5:
            asf = mutate(asf, rng)
        else:
            amc = mutate(amc, rng)
        (folder / "arm.asf").write_text(asf)
        p = folder / "arm_01.amc"
        p.write_text(amc)
        return p

    outcomes, failures, _ = run(write, seed=15)
    assert not failures, report(outcomes, failures)
    assert outcomes["parsed"] > 20 and sum(v for k, v in outcomes.items() if k.endswith("Error")) > 200, outcomes


def test_deepmimic_mutants(tmp_path: Path) -> None:
    frames = [deepmimic_frame(right_knee=-0.1 * i) for i in range(4)]
    clip = '{\n"Loop": "wrap",\n"Frames": [\n' + ",\n".join(repr(f) for f in frames) + "\n]\n}\n"
    (tmp_path / "motions").mkdir()
    (tmp_path / "humanoid.urdf").write_text(handmade_urdf_text())  # parsed once, shared by the clips

    def write(k: int, rng: random.Random) -> Path:
        p = tmp_path / "motions" / f"clip{k}.txt"
        c = mutate(clip, rng)
        p.write_text(c if '"Frames"' in c else '"Frames"' + c)
        return p

    outcomes, failures, _ = run(write, seed=16)
    assert not failures, report(outcomes, failures)
    assert outcomes["parsed"] > 20 and sum(v for k, v in outcomes.items() if k.endswith("Error")) > 200, outcomes


SMALL_URDF = """<robot name="small">
  <link name="base"><inertial><origin rpy="0 0 0" xyz="0 0.1 0"/><mass value="2"/>
    <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial>
    <collision><origin rpy="0 0 0" xyz="0 0.1 0"/><geometry><sphere radius="0.3"/></geometry></collision></link>
  <link name="thigh"><inertial><mass value="1"/></inertial>
    <collision><origin rpy="-1.57 0 0" xyz="0 -0.5 0"/><geometry><capsule length="0.8" radius="0.1"/></geometry>
    </collision></link>
  <link name="foot"><inertial><mass value="0.5"/></inertial>
    <collision><geometry><box size="0.3 0.1 0.2"/></geometry></collision></link>
  <joint name="hip" type="spherical"><parent link="base"/><child link="thigh"/><origin xyz="0 0 0.2"/></joint>
  <joint name="knee" type="revolute"><parent link="thigh"/><child link="foot"/><origin xyz="0 -1 0"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="0"/></joint>
</robot>
"""


def test_urdf_mutants(tmp_path: Path) -> None:
    """URDF mutants: a model with finite arrays, or a MotionFormatError naming the file."""
    rng = random.Random(17)
    outcomes: Counter = Counter()
    failures: list[str] = []
    for k in range(MUTANTS):
        p = tmp_path / f"m{k}.urdf"
        p.write_text(mutate(SMALL_URDF, rng))
        try:
            model = read_humanoid_urdf(p)
        except MotionFormatError as exc:
            outcomes[type(exc).__name__] += 1
            if exc.path != str(p):
                failures.append(f"{p.name}: error names no file: {exc}")
            continue
        except Exception as exc:  # noqa: BLE001 - the point of the test
            failures.append(f"{p.name}: {type(exc).__name__}: {exc}")
            continue
        arrays = (model.masses, model.coms, model.inertias, model.skeleton.offsets, model.axes)
        if not all(np.isfinite(a).all() for a in arrays):
            failures.append(f"{p.name}: a model with non-finite values")
        outcomes["parsed"] += 1
    assert not failures, report(outcomes, failures)
    assert outcomes["parsed"] > 20 and sum(v for k, v in outcomes.items() if k.endswith("Error")) > 200, outcomes


@pytest.mark.parametrize("body", ["Frames: 10000000000", "Frames: 100000000000000000000000",
                                  "Frame Time: 1e-320", "Frame Time: 1e308"])
def test_bvh_header_bombs_are_refused_before_allocating(tmp_path: Path, body: str) -> None:
    text = format_bvh(wiggle(3, 30.0, seed=2))
    key = body.split(":")[0] + ":"
    text = re.sub(rf"^{key}.*$", body, text, count=1, flags=re.M)
    p = tmp_path / "bomb.bvh"
    p.write_text(text)
    with pytest.raises(MotionFormatError) as info:
        read_motion(p)
    assert not isinstance(info.value, ReaderFailure) and info.value.line is not None


def test_catalog_lists_every_failure_and_goes_on(tmp_path: Path) -> None:
    rng = random.Random(3)
    seed = format_bvh(wiggle(12, 30.0, seed=1), decimals=4)
    (tmp_path / "good.bvh").write_text(seed)
    for k in range(40):
        (tmp_path / f"bad{k}.bvh").write_text(mutate(seed, rng))
    (tmp_path / "sidecar.bvh").write_text(seed)
    (tmp_path / "sidecar.json").write_text('{"unit": []}')
    cat = scan_corpus(tmp_path)
    names = {e.path for e in cat.entries} | {e.path for e in cat.errors}
    assert len(names) == 42 and "good.bvh" in {e.path for e in cat.entries}
    assert any(e.path == "sidecar.bvh" and "'unit'" in e.reason for e in cat.errors)
