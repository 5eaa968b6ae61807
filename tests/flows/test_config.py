"""Config validation: defaults, path resolution and errors naming the key and the file."""

from __future__ import annotations

from pathlib import Path

import pytest
from motionweb.flows.config import ConfigError, load_config, packaged_config


@pytest.mark.parametrize("name", ["default.yaml", "demo.yaml"])
def test_shipped_configs_validate(name: str) -> None:
    cfg = load_config(packaged_config(name))
    assert Path(cfg.store.path).is_absolute() and Path(cfg.corpus.path).is_absolute()
    assert cfg.matchweb.valid_a == 0.15 and cfg.features.rates[-1] == 30.0


def test_relative_paths_resolve_against_the_config(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text("corpus: {path: clips}\nstore: {path: 'memory://x'}\n")
    cfg = load_config(tmp_path / "c.yaml")
    assert cfg.corpus.path == str(tmp_path / "clips")
    assert cfg.store.path == "memory://x"


def test_unknown_key_names_key_and_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("matchweb:\n  valid_aa: 0.2\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert "matchweb.valid_aa" in str(info.value) and "bad.yaml" in str(info.value)


def test_wrong_type_names_key_and_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("features:\n  window: five\n")
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert "features.window" in str(info.value) and "bad.yaml" in str(info.value)


def test_digest_changes_with_parameters(tmp_path: Path) -> None:
    a = load_config(packaged_config("default.yaml"))
    (tmp_path / "c.yaml").write_text("matchweb: {valid_a: 0.2}\n")
    b = load_config(tmp_path / "c.yaml")
    assert a.digest("features") == b.digest("features")
    assert a.digest("matchweb") != b.digest("matchweb")


def test_not_yaml_and_missing_file(tmp_path: Path) -> None:
    (tmp_path / "x.yaml").write_text("a: [1, 2\n")
    with pytest.raises(ConfigError, match="x.yaml"):
        load_config(tmp_path / "x.yaml")
    with pytest.raises(ConfigError, match="nope.yaml"):
        load_config(tmp_path / "nope.yaml")


def test_default_yaml_lists_every_key_with_the_models_defaults() -> None:
    """configs/default.yaml is the composed models' defaults written out: same keys, same values."""
    import yaml
    from motionweb.flows.config import Config

    written = yaml.safe_load(packaged_config("default.yaml").read_text())
    assert written == Config().model_dump(mode="json")


def test_stage_parameters_have_one_definition() -> None:
    """The config's sections are the stages' own models (not copies that could drift)."""
    from motionweb.flows.config import Config
    from motionweb.store.catalog import CorpusParams
    from motionweb.tasks.features import FeatureParams
    from motionweb.tasks.guided_warp import WarpParams
    from motionweb.tasks.matchweb.params import MatchWebParams
    from motionweb.tasks.retime import RetimeParams
    from motionweb.tasks.search import SearchParams

    fields = Config.model_fields
    for name, model in [("corpus", CorpusParams), ("features", FeatureParams), ("matchweb", MatchWebParams),
                        ("search", SearchParams), ("warp", WarpParams), ("retime", RetimeParams)]:
        assert fields[name].annotation is model, name


def test_config_digest_ignores_where_things_are(tmp_path: Path) -> None:
    """The same parameters give the same digest from any folder; a parameter changes it."""
    for sub in ("a", "b/c"):
        (tmp_path / sub).mkdir(parents=True)
        (tmp_path / sub / "c.yaml").write_text("corpus: {path: clips}\nmatchweb: {valid_a: 0.2}\n")
    a, b = load_config(tmp_path / "a" / "c.yaml"), load_config(tmp_path / "b" / "c" / "c.yaml")
    assert a.corpus.path != b.corpus.path and a.digest() == b.digest()
    assert a.digest("matchweb") == b.digest("matchweb")
    (tmp_path / "a" / "c.yaml").write_text("corpus: {path: clips}\nmatchweb: {valid_a: 0.25}\n")
    assert load_config(tmp_path / "a" / "c.yaml").digest() != b.digest()


def test_an_old_flat_retime_section_loads_into_the_groups(tmp_path: Path) -> None:
    """A config written before ``retime``'s groups (flat keys) means what its nested twin means:
    the same parameters and the same digest."""
    (tmp_path / "flat.yaml").write_text(
        "retime:\n  contact_height_on: 0.05\n  knots_per_second: 10\n  friction: 0.8\n  lp_solver: highs\n"
        "  floor_heights: {jump_00: 0.0}\n  torque_margin: 2.0\n")
    (tmp_path / "nested.yaml").write_text(
        "retime:\n  torque_margin: 2.0\n  contacts: {height_on: 0.05, friction: 0.8, floor_heights: {jump_00: 0.0}}\n"
        "  polygons: {lp_solver: highs}\n  spline: {knots_per_second: 10}\n")
    flat, nested = load_config(tmp_path / "flat.yaml"), load_config(tmp_path / "nested.yaml")
    assert flat.retime == nested.retime and flat.digest("retime") == nested.digest("retime")
    assert flat.retime.contacts.height_on == 0.05 and flat.retime.spline.knots_per_second == 10.0
    assert flat.retime.contacts.floor_of("jump_00") == 0.0 and flat.retime.contacts.floor_of("walk_00") is None


@pytest.mark.parametrize(("text", "where"), [
    ("retime:\n  contact_heigth_on: 0.05\n", "retime.contact_heigth_on"),
    ("retime:\n  knots_per_second: 10\n  contacts: {heigth_on: 0.05}\n", "retime.contacts.heigth_on"),
    ("retime:\n  contact_height_on: 0.05\n  contacts: {height_on: 0.06}\n", "contacts.height_on both given"),
])
def test_a_wrong_retime_key_names_it_and_the_file(tmp_path: Path, text: str, where: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert where in str(info.value) and "bad.yaml" in str(info.value)
