"""Keys of the content-addressed store: parameter digests, object keys, rate tags (design §9).

Objects are keyed by content: a clip by the SHA-256 of its file, a derived array additionally by
a digest of the parameters that produce it, so objects are shared by every generation that
lists them and a rerun recomputes only what is missing.

Keys (relative to the store root)::

    features/<sha[:2]>/<sha>/<fdig>              a clip's features for one set of feature parameters
    webs/<sha_a[:2]>/<sha_a>-<sha_b>/<wdig>      the (logical) web of an ordered clip pair; stored
                                                 inside a shard under webs/shards/<wdig>/
    grids/<sha_a[:2]>/<sha_a>-<sha_b>/<wdig>     full grid beside a web (matchweb.keep_grids)
"""

from __future__ import annotations

import hashlib
import json
from typing import TYPE_CHECKING, Any, Protocol

from motionweb.store.params import Params

if TYPE_CHECKING:
    from motionweb.store.catalog import CorpusParams


class IndexSettings(Protocol):
    """What keys the index: a run config's corpus, features and matchweb sections (duck-typed, so
    the store needs none of the stages that define them)."""

    corpus: CorpusParams
    features: Params
    matchweb: Params

#: bump when the layout or the meaning of stored arrays changes (enters every parameter digest)
STORE_SCHEMA = 2
#: how a web's values are summed: 2 = every level's cells by the per-cell kernel (float64 sums,
#: tasks.distance.distance_grid_cells: the same bytes on the x86-64 CPUs tests/tasks/test_cpu_bytes.py
#: compiles for); webs of other versions are recomputed (1, before: the coarsest grid by BLAS GEMMs,
#: whose bits depend on the CPU's kernel)
WEB_VALUES = 2
#: web shards live under webs/ next to the (logical) web keys webs/<sha_a[:2]>/...
SHARDS = "webs/shards"


def _digest(data: Any) -> str:
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()


def feature_params(cfg: IndexSettings) -> dict[str, Any]:
    """Everything that changes a clip's features at one rate (the rate list itself excluded)."""
    feats = cfg.features.model_dump(mode="json")
    feats.pop("rates", None)
    corpus = cfg.corpus
    return {
        "schema": STORE_SCHEMA,
        "features": feats,
        "up_axis": corpus.up_axis,
        "length_unit": corpus.length_unit,
        "scale_to_m": corpus.scale_to_m,
    }


def feature_digest(cfg: IndexSettings) -> str:
    """Parameter hash keying features: clip sha256 + this + rate (design §9)."""
    return _digest(feature_params(cfg))[:16]


def web_params(cfg: IndexSettings) -> dict[str, Any]:
    """Everything that changes a web: feature parameters, the rate ladder and the matchweb section."""
    mw = cfg.matchweb.model_dump(mode="json")
    mw.pop("keep_grids", None)  # storing grids on the side does not change a web
    return {
        "schema": STORE_SCHEMA,
        "values": WEB_VALUES,
        "features": feature_params(cfg),
        "rates": sorted(float(r) for r in cfg.features.rates),
        "matchweb": mw,
    }


def web_digest(cfg: IndexSettings) -> str:
    """Parameter hash keying webs: ordered pair of clip hashes + this (design §9)."""
    return _digest(web_params(cfg))[:16]


def rate_tag(rate: float) -> str:
    """Array name of one feature rate, e.g. ``r30`` or ``r7.5``."""
    return f"r{float(rate):g}"


def feature_key(sha: str, fdigest: str) -> str:
    return f"features/{sha[:2]}/{sha}/{fdigest}"


def web_key(sha_a: str, sha_b: str, wdigest: str) -> str:
    """Key of the web whose rows are clip ``sha_a`` and columns clip ``sha_b``."""
    return f"webs/{sha_a[:2]}/{sha_a}-{sha_b}/{wdigest}"


def grid_key(web: str) -> str:
    return "grids/" + web.removeprefix("webs/")


def web_digest_of(key: str) -> str:
    """The web parameter digest at the end of a web key (names the key's shard folder)."""
    return key.rsplit("/", 1)[-1]
