"""One request model per on-demand command (issue 23), shared by the CLI, the forwarding client
(``flows/app/client.py``) and the service's API (``flows/app/api.py``).

Each model checks everything that can be checked without the store or the data (ranges, finite
numbers, exclusive options) and fails with the CLI's message naming the field; the CLI builds the
model from its options (:func:`parse`), the API receives it as its JSON body, the client sends
``model.wire()``. What needs the store (the clip exists, the window lies inside it) is each
command's plan (``flows/query.plan_query``, ``flows/space.plan_space``, ``flows/warp``'s plan).

Models import only pydantic (and the pydantic-only parameter types of ``tasks/params``): a forwarded
command builds its request before anything heavy loads.
"""

from __future__ import annotations

import math
from typing import Any, Literal, Self, TypeVar

from motionweb.tasks.params.retime import Objective
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

#: longest clip name or path a request may carry
MAX_NAME = 300


class Request(BaseModel):
    """Base of the request models: unknown fields are errors, every float must be finite."""

    model_config = ConfigDict(extra="forbid")

    @model_validator(mode="after")
    def _finite(self) -> Self:
        for name in type(self).model_fields:
            v = getattr(self, name)
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"{name} must be a finite number, got {v}")
        return self

    def wire(self) -> dict[str, Any]:
        """The JSON body the forwarding client sends (and the run record keeps)."""
        return self.model_dump(mode="json", by_alias=True)


class QueryWindow(Request):
    """A query M1[a, b] (KG04 §3.3): ``clip`` is a corpus path, a unique file stem or (in the
    service) an index id or an upload's id (``up-...``: a clip of the user's own, searched as
    ``--query-file`` searches a file: its webs built on demand); ``start`` and ``end`` in seconds; at most one of ``threshold`` (absolute
    ε) and ``quantile`` (ε as that quantile of the searched webs' values); with neither, the
    default rule (``tasks.ranking.choose_epsilon``: a multiple of the query's nearest match)."""

    clip: str = Field(min_length=1, max_length=MAX_NAME)
    start: float
    end: float
    threshold: float | None = None
    quantile: float | None = None

    @model_validator(mode="after")
    def _window(self) -> Self:
        return check_window(self)


def check_window(m: Any) -> Any:
    """The checks of a query window (``clip``, ``start``, ``end``, ``threshold``, ``quantile``)."""
    if m.threshold is not None and m.quantile is not None:
        raise ValueError("give at most one of threshold (absolute ε) and quantile (ε as a quantile)")
    if m.threshold is not None and m.threshold < 0:
        raise ValueError(f"threshold must be ≥ 0, got {m.threshold}")
    if m.quantile is not None and not 0.0 < m.quantile < 1.0:
        raise ValueError(f"quantile must lie in (0, 1), got {m.quantile}")
    if not m.end > m.start:
        raise ValueError(f"the query must end after it starts, got {m.start} s .. {m.end} s")
    return m


class SearchQuery(QueryWindow):
    """``motionweb search`` as the service runs it: the query, its tiers and scope, and whether the
    matches are registered (KG04 §4.1; the field ``register_``, ``register`` on the wire and in
    every constructor: a model attribute named ``register`` would shadow ``ABCMeta.register``)."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)
    tiers: int | None = None
    all_categories: bool | None = None
    register_: bool = Field(default=False, alias="register")

    @model_validator(mode="after")
    def _tiers(self) -> Self:
        if self.tiers is not None and self.tiers < 1:
            raise ValueError(f"tiers must be ≥ 1, got {self.tiers}")
        return self


class QueryRequest(SearchQuery):
    """``motionweb search``: the query and the client's output folders (``out``, ``export``: every
    match as BVH). A forwarded request's folders are only recorded by the service, which writes
    nothing where a request says."""

    export: str | None = Field(default=None, max_length=1000)
    out: str | None = Field(default=None, max_length=1000)
    #: format of the exported and registered motions (BVH, or glTF binary: design §11)
    format: Literal["bvh", "glb"] = "bvh"

    def search_query(self) -> SearchQuery:
        """The request without the client's folders and format (what the service searches)."""
        return SearchQuery(**self.model_dump(exclude={"export", "out", "format"}, by_alias=True))


class SpaceRequest(Request):
    """``motionweb parameterize`` (KG04 §4): the query window (as :class:`QueryWindow`), the
    parameter (``KIND[:JOINT[@SECONDS]]``), the random weight samples, the plot folder. Its fields
    keep their recorded order (a stored space records its request)."""

    clip: str = Field(min_length=1, max_length=MAX_NAME)
    start: float
    end: float
    param: str = Field(min_length=1, max_length=MAX_NAME)
    threshold: float | None = None
    quantile: float | None = None
    samples: int | None = None
    out: str | None = Field(default=None, max_length=1000)

    @model_validator(mode="after")
    def _checks(self) -> Self:
        if self.samples is not None and self.samples < 1:
            raise ValueError(f"--samples must be ≥ 1, got {self.samples}")
        return check_window(self)

    def query(self) -> QueryRequest:
        """The search that finds the space's examples."""
        return QueryRequest(clip=self.clip, start=self.start, end=self.end, threshold=self.threshold,
                            quantile=self.quantile)


class SynthesizeRequest(Request):
    """``motionweb synthesize`` (KG04 §4.3): a target parameter, metres."""

    target: list[float] = Field(min_length=1, max_length=3)


class BlendRequest(Request):
    """``motionweb blend`` (KG04 §4): weights by example (corpus path or stem), summing to 1."""

    weights: dict[str, float] = Field(min_length=1, max_length=256)

    @model_validator(mode="after")
    def _finite_weights(self) -> Self:
        bad = [k for k, v in self.weights.items() if not math.isfinite(v)]
        if bad:
            raise ValueError(f"weight of {bad[0]!r} must be a finite number")
        return self


class WarpRequest(Request):
    """``motionweb warp`` (HDP07): files, the output length (exactly one of ``duration`` seconds,
    ``frames``, ``unconstrained``) and keytimes as (input seconds, output seconds) pairs; ``skip``
    overrides the config's skip limit. Paths are the CLI's: the service never takes this model."""

    input: str
    out: str
    reference: str | None = None
    duration: float | None = None
    frames: int | None = None
    unconstrained: bool = False
    keytimes: tuple[tuple[float, float], ...] = ()
    skip: int | None = None
    fast: bool = False
    backward: bool = False
    plot: str | None = None

    @model_validator(mode="after")
    def _length(self) -> Self:
        if sum([self.duration is not None, self.frames is not None, self.unconstrained]) != 1:
            raise ValueError("give exactly one of --duration SECONDS, --frames M or --unconstrained")
        if self.duration is not None and not self.duration > 0:
            raise ValueError(f"--duration must be positive, got {self.duration:g}")
        return self


class RetimeRequest(Request):
    """``motionweb retime`` (MPS06): the clip, the output, a duration and/or keytimes (source
    seconds, output seconds), gravity (m/s², None: the config's up axis at 9.81), per-joint mass
    and weight factors (MPS06 Fig. 11), the objective (None: the config's ``retime.spline.objective``)
    and a plot folder."""

    input_path: str
    out: str
    duration: float | None = None
    keytimes: list[tuple[float, float]] = Field(default_factory=list)
    gravity: list[float] | None = Field(default=None, min_length=3, max_length=3)
    mass: dict[str, float] = Field(default_factory=dict)
    weight_factors: dict[str, float] = Field(default_factory=dict)
    objective: Objective | None = None
    plot_dir: str | None = None

    @model_validator(mode="after")
    def _timing(self) -> Self:
        if self.duration is None and not self.keytimes:
            raise ValueError("give --duration SECONDS and/or --keytime SRC_S:OUT_S")
        if self.duration is not None and not self.duration > 0:
            raise ValueError(f"--duration must be positive, got {self.duration:g}")
        for option, factors in (("--mass", self.mass), ("--weight", self.weight_factors)):
            for joint, f in factors.items():
                if not (math.isfinite(f) and f > 0):
                    raise ValueError(f"{option} {joint}={f:g}: expected JOINT=FACTOR with a positive factor")
        return self


class ExportRequest(Request):
    """``motionweb export`` / ``mirror`` / ``cleanup``: the clip, the output, its format (None: by
    the output's suffix) and the root-motion mode (None: the config's ``root_motion.mode``)."""

    input: str
    out: str
    format: Literal["bvh", "glb", "fbx"] | None = None
    root_motion: Literal["keep", "in-place"] | None = None


class CatalogRequest(Request):
    """``motionweb catalog``: the corpus folder to scan; ``as_json``: print the catalog as JSON."""

    corpus: str = Field(min_length=1)
    as_json: bool = False


class PreviewRequest(Request):
    """``motionweb preview``: a stick-figure GIF of a clip, subsampled to at most ``max_frames``
    frames, played at ``fps``, drawn with ``up`` as the clip's vertical axis."""

    motion: str = Field(min_length=1)
    out: str = Field(min_length=1)
    max_frames: int = Field(120, ge=2, le=10_000)
    fps: float = Field(15.0, gt=0, le=100)
    up: Literal["x", "y", "z"] = "y"


class PlotWebRequest(Request):
    """``motionweb plot-web``: the distance grid of two clips with its web (KG04 Figs. 4, 7)."""

    clip_a: str = Field(min_length=1, max_length=MAX_NAME)
    clip_b: str = Field(min_length=1, max_length=MAX_NAME)
    out: str = Field("web.png", min_length=1)


class GcRequest(Request):
    """``motionweb gc``: generations kept, the current one and those before it (None: the config's
    ``index.keep_generations``, which the index's own clean-up keeps)."""

    keep: int | None = Field(None, ge=1)


M = TypeVar("M", bound=Request)


def message(errors: list[Any]) -> str:
    """Validation errors (``ValidationError.errors()``, FastAPI's too) as the CLI prints them: one
    clause per problem naming its field (FastAPI's ``body`` / ``query`` / ``path`` prefix off)."""
    parts = []
    for e in errors:
        where = list(e["loc"])
        loc = ".".join(str(p) for p in (where[1:] if where and where[0] in ("body", "query", "path") else where))
        msg = str(e["msg"]).removeprefix("Value error, ")
        parts.append(f"{loc}: {msg}" if loc else msg)
    return "; ".join(parts)


def parse(model: type[M], **fields: Any) -> M:
    """``model(**fields)``, a ValueError with :func:`message` when it is invalid."""
    try:
        return model(**fields)
    except ValidationError as exc:
        raise ValueError(message(exc.errors())) from None
