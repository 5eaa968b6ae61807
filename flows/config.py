"""Run configuration: YAML files validated by pydantic models.

Every run is driven by one config file. Unknown keys and wrong types fail with a message naming
the key path and the file. Each stage owns one section; defaults follow the papers.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid")


class CategoryRule(_Section):
    """Clips whose corpus-relative path matches ``pattern`` (Python regex, searched) get ``category``."""

    pattern: str
    category: str


class CorpusConfig(_Section):
    path: str = "demo-corpus"
    #: regex rules tried in order; the first folder level labels clips no rule matches
    category_rules: list[CategoryRule] = Field(default_factory=list)
    #: CSV with columns ``path,category`` (paths relative to the corpus); overrides rules
    manifest: str | None = None
    #: length unit of files that do not declare one (BVH): m, cm, mm, in, ft
    length_unit: str | None = None
    scale_to_m: float | None = None
    up_axis: Literal["x", "y", "z"] = "y"


class DemoConfig(_Section):
    """The synthetic demo corpus the project generates itself."""

    seed: int = 7
    variants_per_category: int = 3
    fps: float = 60.0
    #: the search `motionweb demo` ends with (clip, seconds, ε as a quantile of the webs' values)
    query_clip: str = "walk/walk_00.bvh"
    query_start: float = 1.0
    query_end: float = 2.5
    query_quantile: float = 0.8


class FeatureConfig(_Section):
    """Point-cloud features (SPEC §3)."""

    rates: list[float] = Field(default_factory=lambda: [10.0, 20.0, 30.0])
    window: int = 5
    joint_weights: dict[str, float] = Field(default_factory=dict)
    dtype: Literal["float32", "float64"] = "float32"


class MatchWebConfig(_Section):
    """Match webs (SPEC §4, KG04 §3.1-3.2)."""

    valid_a: float = 0.15
    slope_k: int = 3
    min_chain_s: float = 0.25
    bridge_max_s: float = 2.0
    self_band_s: float = 0.25
    keep_grids: bool = False


class DaskConfig(_Section):
    #: address of an existing dask.distributed scheduler; None starts a local cluster
    address: str | None = None
    n_workers: int | None = None
    threads_per_worker: int = 1
    #: local cluster only: worker processes (True), threads in this process (False), or None =
    #: threads for small runs (few grid cells to compute), processes otherwise
    processes: bool | None = None


class StoreConfig(_Section):
    #: local folder or any fsspec URL
    path: str = "motionweb-store"


class IndexConfig(_Section):
    chunk_by: Literal["category", "none"] = "category"
    schedule: str = "0 2 * * *"


class SearchConfig(_Section):
    """Search and match graph (SPEC §5)."""

    overlap_redundant: float = 0.5
    new_node_below: float = 0.2
    merge_above: float = 0.8
    max_tiers: int = 10
    all_categories: bool = False


class WarpConfig(_Section):
    """Guided time warping (SPEC §7, HDP07 §3)."""

    skip: int = 8
    neighbours: int = 3
    filter_width: int = 5
    weights: tuple[float, float, float] = (1.0, 1.0, 1.0)
    heuristic_rate: int = 8
    #: half-width (working frames) of the full-rate band around the coarse solution (--fast)
    band: int = 48
    #: moving-average width of the warp, output frames (HDP07 §3.4)
    smooth_width: int = 5
    #: average each output frame over the local compression (HDP07 §3.4)
    adaptive_smoothing: bool = True
    #: divide pose/velocity/acceleration features by the reference's RMS spread of each
    normalize: bool = True
    #: velocities include the root's travel and turning (differences in the middle frame's torso frame)
    root_motion: bool = True


class RetimeConfig(_Section):
    """Physics-based retiming (SPEC §8, MPS06 §3)."""

    body_model: Literal["cylinders", "table"] = "cylinders"
    total_mass: float | None = None
    friction: float = 0.5
    contact_height: float = 0.05
    contact_speed: float = 0.3
    torque_margin: float = 1.5
    samples_per_frame: int = 4
    #: MPS06 Eqn. 14 weights, both unit-free: α on the squared distance to the feasible polygon
    #: priced as unexplained root force in body weights, β on the mean squared torque deviation
    #: in units of the torque limits
    alpha: float = 1.0
    beta: float = 0.1
    objective: Literal["match", "minimize"] = "match"
    ground_height: float = 0.0
    #: per clip name: {foot joint: [[start_s, end_s], ...]} replacing detected contacts
    contact_intervals: dict[str, dict[str, list[tuple[float, float]]]] = Field(default_factory=dict)
    #: retime clips with no ground contact as pure flight instead of failing
    allow_flight_only: bool = False
    speed_max: float = 6.0
    knots_per_second: float = 8.0


class Config(_Section):
    corpus: CorpusConfig = Field(default_factory=CorpusConfig)
    demo: DemoConfig = Field(default_factory=DemoConfig)
    features: FeatureConfig = Field(default_factory=FeatureConfig)
    matchweb: MatchWebConfig = Field(default_factory=MatchWebConfig)
    dask: DaskConfig = Field(default_factory=DaskConfig)
    store: StoreConfig = Field(default_factory=StoreConfig)
    index: IndexConfig = Field(default_factory=IndexConfig)
    search: SearchConfig = Field(default_factory=SearchConfig)
    warp: WarpConfig = Field(default_factory=WarpConfig)
    retime: RetimeConfig = Field(default_factory=RetimeConfig)
    output: str = "motionweb-out"

    def digest(self, section: str | None = None) -> str:
        """SHA-256 of the canonical JSON of the config (or of one section)."""
        data = self.model_dump(mode="json") if section is None else getattr(self, section).model_dump(mode="json")
        return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()


class ConfigError(ValueError):
    """A config file that does not validate; the message names the file and the keys."""


CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"


def load_config(path: str | Path | None = None) -> Config:
    """Load and validate a YAML config (``configs/default.yaml`` when ``path`` is None).

    Relative paths inside the file (corpus, store, output, manifest) are taken relative to the
    config file's folder, so a config means the same thing from any working directory.
    """
    path = Path(path) if path is not None else CONFIG_DIR / "default.yaml"
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
    return resolve_paths(cfg, path.parent)


def resolve_paths(cfg: Config, base: Path) -> Config:
    """Make relative local paths absolute against ``base`` (fsspec URLs are left alone)."""

    def fix(p: str | None) -> str | None:
        if p is None or "://" in p or Path(p).is_absolute():
            return p
        return str((base / p).resolve())

    cfg.corpus.path = fix(cfg.corpus.path)
    cfg.corpus.manifest = fix(cfg.corpus.manifest)
    cfg.store.path = fix(cfg.store.path)
    cfg.output = fix(cfg.output)
    return cfg
