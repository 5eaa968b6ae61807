"""Parameter digests keying the store (design §9)."""

from __future__ import annotations

from motionweb.flows.config import Config
from motionweb.store.keys import feature_digest, web_digest


def test_parameter_digests():
    base = Config()
    mw = Config.model_validate({"matchweb": {"valid_a": 0.3}})
    assert web_digest(mw) != web_digest(base)
    assert feature_digest(mw) == feature_digest(base)  # features are reused across web parameters
    feat = Config.model_validate({"features": {"window": 7}})
    assert feature_digest(feat) != feature_digest(base) and web_digest(feat) != web_digest(base)
    rates = Config.model_validate({"features": {"rates": [10.0, 20.0, 60.0]}})
    assert feature_digest(rates) == feature_digest(base)  # rates are part of the feature key itself
    assert web_digest(rates) != web_digest(base)
    grids = Config.model_validate({"matchweb": {"keep_grids": True}})
    assert web_digest(grids) == web_digest(base)
