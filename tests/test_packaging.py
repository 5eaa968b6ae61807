"""The installed package: one `motionweb` namespace, layers that import only downwards, configs as data."""

from __future__ import annotations

import ast
import subprocess
import sys
from importlib import resources
from pathlib import Path

import motionweb.flows
import motionweb.store
import motionweb.tasks

LAYERS = {"store": 0, "tasks": 1, "flows": 2}
#: frameworks only the flows may import
FLOW_ONLY = ("prefect", "dask", "distributed", "typer", "yaml", "matplotlib", "fastapi", "uvicorn")


def _run(code: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=120)


def test_old_top_level_names_are_not_importable(tmp_path: Path) -> None:
    for name in ("store", "tasks", "flows", "configs"):
        r = _run(f"import {name}", tmp_path)
        assert r.returncode != 0 and "ModuleNotFoundError" in r.stderr, name
    r = _run("import motionweb.store.motion, motionweb.tasks.search, motionweb.flows.commands.cli; print('ok')", tmp_path)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


def test_configs_ship_as_package_data() -> None:
    names = {p.name for p in resources.files("motionweb.configs").iterdir()}
    assert {"default.yaml", "demo.yaml"} <= names


def _imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text())
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append(node.module)
    return out


def test_each_layer_imports_only_the_layers_below_it() -> None:
    problems = []
    for pkg in (motionweb.store, motionweb.tasks, motionweb.flows):
        layer = pkg.__name__.split(".")[1]
        for path in Path(pkg.__path__[0]).rglob("*.py"):
            for mod in _imports(path):
                parts = mod.split(".")
                if parts[0] == "motionweb" and len(parts) > 1 and LAYERS.get(parts[1], -1) > LAYERS[layer]:
                    problems.append(f"{path.name} ({layer}) imports {mod}")
                if layer != "flows" and parts[0] in FLOW_ONLY:
                    problems.append(f"{path.name} ({layer}) imports the framework {mod}")
    assert not problems, problems


def test_no_private_name_crosses_a_module() -> None:
    """A kernel another module uses is public: no `from motionweb.x import _name`."""
    problems = []
    for pkg in (motionweb.store, motionweb.tasks, motionweb.flows):
        for path in Path(pkg.__path__[0]).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("motionweb"):
                    problems += [f"{path.name}: {node.module}.{a.name}" for a in node.names if a.name.startswith("_")]
    assert not problems, problems


def test_lint_bans_the_bare_folder_imports(tmp_path: Path) -> None:
    """The ruff rule (TID251, configured in pyproject.toml) flags `import store` and friends."""
    import shutil

    ruff = shutil.which("ruff") or str(Path(sys.executable).with_name("ruff"))
    root = Path(__file__).resolve().parent.parent
    bad = tmp_path / "bad.py"
    bad.write_text("import store\nfrom tasks.search import search\nfrom motionweb.store import motion\n")
    r = subprocess.run([ruff, "check", "--no-cache", "--select", "TID251", "--config", str(root / "pyproject.toml"),
                        str(bad)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1, r.stdout + r.stderr
    assert r.stdout.count("TID251") == 2, r.stdout  # the two bare imports, not motionweb.store
    clean = subprocess.run([ruff, "check", "--no-cache", "--select", "TID251", "--config", str(root / "pyproject.toml"),
                            *(str(root / d) for d in ("store", "tasks", "flows", "tests", "bench"))],
                           capture_output=True, text=True, timeout=120)
    assert clean.returncode == 0, clean.stdout
