"""Package discovery for the design card's layout: the top-level folders store/, tasks/, flows/ and
configs/ install as motionweb.store, motionweb.tasks, motionweb.flows and motionweb.configs, with every
subpackage (a folder holding __init__.py, or data files only) found here, so a new one can never be left out of a wheel.
Everything else about the project is in pyproject.toml."""

from pathlib import Path

from setuptools import setup

ROOTS = ("store", "tasks", "flows", "configs")
here = Path(__file__).parent
package_dir = {}
for root in ROOTS:
    for init in sorted((here / root).rglob("__init__.py")):
        folder = init.parent.relative_to(here)
        package_dir["motionweb." + ".".join(folder.parts)] = folder.as_posix()
# folders of data only (the app's page): packages too, whose files pyproject.toml's package-data
# names (setuptools warns that a data folder outside `packages` will be left out of wheels)
for root in ROOTS:
    for folder in sorted(p for p in (here / root).rglob("*") if p.is_dir()):
        rel = folder.relative_to(here)
        if (not (folder / "__init__.py").exists() and "__pycache__" not in rel.parts
                and not any(part.startswith(".") for part in rel.parts)
                and any(f.is_file() and f.suffix != ".py" for f in folder.iterdir())):
            package_dir["motionweb." + ".".join(rel.parts)] = rel.as_posix()

setup(packages=sorted(package_dir), package_dir=package_dir)
