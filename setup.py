"""Package discovery for the design card's layout: the top-level folders store/, tasks/, flows/ and
configs/ install as motionweb.store, motionweb.tasks, motionweb.flows and motionweb.configs, with every
subpackage (a folder holding __init__.py) found here, so a new one can never be left out of a wheel.
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

setup(packages=sorted(package_dir), package_dir=package_dir)
