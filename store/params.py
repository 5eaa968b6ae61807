"""The base of every stage's parameter model.

Each stage keeps its parameters in one pydantic model beside its code (``CorpusParams`` in
:mod:`motionweb.store.catalog`, ``FeatureParams`` in :mod:`motionweb.tasks.features`, ...), with its
defaults in that one place; the run config (:mod:`motionweb.flows.config`) composes them into the
sections of a YAML file. Unknown keys are errors, so a typo in a config never passes silently.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Params(BaseModel):
    """A stage's parameters: validated, unknown keys rejected, defaults the papers' values."""

    model_config = ConfigDict(extra="forbid")
