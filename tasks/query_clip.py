"""A clip from outside the index as a query (KG04 §3.3; issue 24): its features, its match webs
against the indexed clips built on demand, and a web source that adds them to the index's.

The features and webs are those the index would compute for the clip (``tasks.features``,
``tasks.matchweb.build_web_operands``, the same parameters), so a clip that is in the index,
searched as a file under another name, finds the same matches. Cost: features O(F·P) per rate, one
web per compatible indexed clip (its coarse grid O(F·Fb·P / 9), then refinement along chains).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping

import numpy as np
from motionweb.store.motion import Motion
from motionweb.store.threads import map_in_threads
from motionweb.store.web import MatchWeb, transpose
from motionweb.store.webs import WebSource
from motionweb.tasks.distance import ClipOperands
from motionweb.tasks.features import feature_set
from motionweb.tasks.matchweb.build import build_web_operands
from motionweb.tasks.params.features import FeatureParams
from motionweb.tasks.params.matchweb import MatchWebParams

#: (features by rate, point weights) of an indexed clip, as ``MotionStore.read_features`` gives them
Features = tuple[dict[float, np.ndarray], np.ndarray]


def clip_operands(motion: Motion, fcfg: FeatureParams, up: str) -> tuple[dict[float, np.ndarray], np.ndarray,
                                                                         dict[float, ClipOperands]]:
    """The clip's features by rate ((F_r, P, 3) each), point weights (P,) and distance operands,
    as the index computes them (:func:`~motionweb.tasks.features.feature_set`)."""
    by_rate, weights = feature_set(motion, fcfg, up)
    return by_rate, weights, ClipOperands.by_rate(by_rate, weights)


def query_clip_webs(motion: Motion, mine: dict[float, ClipOperands], others: Mapping[str, str],
                    features_of: Callable[[str], Features], wcfg: MatchWebParams) -> dict[str, MatchWeb]:
    """Webs of ``motion`` (rows; ``mine``: its operands, :func:`clip_operands`) against each
    indexed clip of ``others`` (name -> its SHA-256),
    and against itself under the key ``""`` (the index has a self web per clip).
    ``features_of(name)`` reads an indexed clip's stored features. Each web is built the way the
    index builds that pair (``flows/index.plan_pairs``: the clip with the smaller hash gives the
    rows), then oriented with ``motion`` as rows, so it is the web the index would store. Cost: one
    web per clip of ``others``, built on every core (threads)."""
    sha = motion.content_hash
    for name, other_sha in others.items():
        if other_sha == sha:
            raise ValueError(f"the query clip is indexed as {name!r}: search that clip")

    stored = {name: features_of(name) for name in others}  # read here, in order

    def web_with(name: str) -> MatchWeb:
        theirs = ClipOperands.by_rate(*stored[name])
        return (build_web_operands(mine, theirs, wcfg, False) if sha < others[name]
                else transpose(build_web_operands(theirs, mine, wcfg, False)))

    # the web kernels release the GIL (nogil): one thread per core builds them, in the order given
    built = map_in_threads(web_with, list(others))
    return {"": build_web_operands(mine, mine, wcfg, True), **dict(zip(others, built, strict=True))}


class WithQueryClip(Mapping[str, list[tuple[str, MatchWeb]]]):
    """A :data:`~motionweb.store.webs.WebSource`: ``base`` (the index's webs) plus the clip
    ``name`` and its webs ``webs`` (from :func:`query_clip_webs`: ``""`` its self web, else an
    indexed clip's name), each seen from both sides."""

    def __init__(self, base: WebSource, name: str, webs: dict[str, MatchWeb]):
        if name in base:
            raise ValueError(f"the query clip's name {name!r} is an indexed clip's")
        self.base, self.name, self.webs = base, name, webs
        self._transposed: dict[str, MatchWeb] = {}

    def __getitem__(self, clip: str) -> list[tuple[str, MatchWeb]]:
        if clip == self.name:
            return [(self.name if other == "" else other, web) for other, web in self.webs.items()]
        out = list(self.base[clip]) if clip in self.base else []
        if clip in self.webs:
            if clip not in self._transposed:
                self._transposed[clip] = transpose(self.webs[clip])
            out.append((self.name, self._transposed[clip]))
        if not out:
            raise KeyError(clip)
        return out

    def __iter__(self) -> Iterator[str]:
        yield self.name
        yield from self.base

    def __len__(self) -> int:
        return len(self.base) + 1

    def all_webs(self) -> list[MatchWeb]:
        """Every web once: the base's and the query clip's."""
        return [*self.base.all_webs(), *self.webs.values()]
