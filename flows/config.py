"""Run configuration: one YAML file composed of every stage's parameter model.

Every run is driven by one config file. Each section is the parameter model that lives beside its
stage (``corpus`` = :class:`~motionweb.store.catalog.CorpusParams`, ``features`` =
:class:`~motionweb.tasks.features.FeatureParams`, ...), with its defaults in that model only;
the sections that only the flows use (demo, dask, store, index) are defined here, the service's
(app) in :mod:`motionweb.flows.app.params`. Unknown keys
and wrong types fail with a message naming the key path and the file. ``configs/default.yaml``
(package data, :mod:`motionweb.configs`) lists every section and key with its default.
"""

from __future__ import annotations

import hashlib
import json
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import yaml
from motionweb.flows.app.params import AppParams
from motionweb.flows.paths import resolve_path
from motionweb.store.catalog import CorpusParams
from motionweb.store.params import Params
from motionweb.tasks.params.blend import BlendParams
from motionweb.tasks.params.features import FeatureParams
from motionweb.tasks.params.matchweb import MatchWebParams
from motionweb.tasks.params.mirror import MirrorParams
from motionweb.tasks.params.parameterize import ParameterizeParams
from motionweb.tasks.params.retime import RetimeParams
from motionweb.tasks.params.rootmotion import RootMotionParams
from motionweb.tasks.params.search import SearchParams
from motionweb.tasks.params.shortlist import ShortlistParams
from motionweb.tasks.params.warp import WarpParams
from pydantic import Field, ValidationError

if TYPE_CHECKING:
    from motionweb.store.motion import Motion


class DemoConfig(Params):
    """The synthetic demo corpus the project generates itself."""

    seed: int = 7
    variants_per_category: int = 3
    #: per-category variant counts overriding variants_per_category (e.g. {reach: 12, walk: 24})
    variants: dict[str, int] = Field(default_factory=dict)
    fps: float = 60.0
    #: the search `motionweb demo` ends with (clip, seconds, ε as a quantile of the webs' values)
    query_clip: str = "walk/walk_00.bvh"
    query_start: float = 1.0
    query_end: float = 2.5
    query_quantile: float = 0.8


class DaskConfig(Params):
    #: address of an existing dask.distributed scheduler; None starts a local cluster
    address: str | None = None
    n_workers: int | None = None
    threads_per_worker: int = 1
    #: local cluster only: worker processes (True), threads in this process (False), or None =
    #: threads for small runs (few grid cells to compute), processes otherwise
    processes: bool | None = None


class StoreConfig(Params):
    #: local folder or any fsspec URL; for s3:// the endpoint and credentials come from the AWS
    #: environment (AWS_ENDPOINT_URL_S3, AWS_ACCESS_KEY_ID, ...), never from the config (README)
    path: str = "motionweb-store"


class IndexConfig(Params):
    chunk_by: Literal["category", "none"] = "category"
    schedule: str = "0 2 * * *"
    #: generations kept by the gc after each run (the current one and those committed before it)
    keep_generations: int = Field(3, ge=1)
    #: MiB of clip distance operands each Dask worker keeps between the pairs it computes (least
    #: recently used dropped first; about 48·frames·points bytes per clip and rate)
    operand_cache_mb: float = Field(512.0, gt=0)
    #: build webs only for the clip pairs shortlisted by k-NN over pose windows (``tasks/shortlist.py``),
    #: in each chunk; off: every pair of a chunk (KG04 §3). Meant for ``chunk_by: none``
    shortlist: ShortlistParams = Field(default_factory=ShortlistParams)


#: the config's path fields, which say where things are, not how they are computed
LOCATIONS: dict = {"corpus": {"path", "manifest"}, "store": {"path"}, "output": True}


class Config(Params):
    corpus: CorpusParams = Field(default_factory=CorpusParams)
    demo: DemoConfig = Field(default_factory=DemoConfig)
    features: FeatureParams = Field(default_factory=FeatureParams)
    matchweb: MatchWebParams = Field(default_factory=MatchWebParams)
    dask: DaskConfig = Field(default_factory=DaskConfig)
    store: StoreConfig = Field(default_factory=StoreConfig)
    index: IndexConfig = Field(default_factory=IndexConfig)
    search: SearchParams = Field(default_factory=SearchParams)
    warp: WarpParams = Field(default_factory=WarpParams)
    retime: RetimeParams = Field(default_factory=RetimeParams)
    blend: BlendParams = Field(default_factory=BlendParams)
    parameterize: ParameterizeParams = Field(default_factory=ParameterizeParams)
    mirror: MirrorParams = Field(default_factory=MirrorParams)
    root_motion: RootMotionParams = Field(default_factory=RootMotionParams)
    app: AppParams = Field(default_factory=AppParams)
    output: str = "motionweb-out"

    def digest(self, section: str | None = None) -> str:
        """SHA-256 of the canonical JSON of the config's parameters (or of one section's).

        Locations are not parameters: the corpus, manifest, store and output paths are left out,
        so the same config gives the same digest on every machine and from every folder (the
        inputs themselves are identified by their content hashes in the run records)."""
        data = self.model_dump(mode="json", exclude=LOCATIONS)
        data = data if section is None else data[section]
        return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()


class ConfigError(ValueError):
    """A config file that does not validate; the message names the file and the keys."""


def packaged_config(name: str) -> Path:
    """A config shipped with the package (``default.yaml``, ``demo.yaml``), as a file path."""
    ref = resources.files("motionweb.configs") / name
    with resources.as_file(ref) as path:  # a real file for an installed package (no zip import)
        return Path(path)


def load_config(path: str | Path | None = None) -> Config:
    """Load and validate a YAML config (``configs/default.yaml`` when ``path`` is None).

    Relative paths inside the file (corpus, store, output, manifest) are taken relative to the
    config file's folder, so a config means the same thing from any working directory; those of
    the packaged default (no ``path``) relative to the working directory.
    """
    base = None if path is not None else Path.cwd()
    path = Path(path) if path is not None else packaged_config("default.yaml")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read config: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping of sections")
    try:
        cfg = Config.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors()
        )
        raise ConfigError(f"{path}: {problems}") from None
    return resolve_paths(cfg, base or path.parent)


def resolve_paths(cfg: Config, base: Path) -> Config:
    """Make relative local paths absolute against ``base`` (fsspec URLs are left alone)."""
    cfg.corpus.path = resolve_path(cfg.corpus.path, base)
    cfg.corpus.manifest = resolve_path(cfg.corpus.manifest, base)
    cfg.store.path = resolve_path(cfg.store.path, base)
    cfg.output = resolve_path(cfg.output, base)
    return cfg


def load_motion(path: str | Path, config: Config) -> Motion:
    """A user's clip (.bvh, .amc with its ASF, DeepMimic .txt) read with the config's units: a BVH
    that declares no length unit takes ``corpus.length_unit`` / ``scale_to_m``. ValueError naming
    a missing file; the readers' MotionFormatError otherwise. The readers load on use (this module
    stays light)."""
    from motionweb.store.formats import read_motion

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{p}: no such file")
    return read_motion(p, unit=config.corpus.length_unit, scale_to_m=config.corpus.scale_to_m)
