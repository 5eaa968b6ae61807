"""``motionweb verify`` and ``motionweb gc``: integrity and housekeeping of a config's store (design §9)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:  # zarr and numpy load on use: the CLI starts fast for a forwarded query
    from motionweb.store.zarr_store import MotionStore


def _store(config: Path) -> MotionStore:
    from motionweb.flows.cli import config_or_fail
    from motionweb.store.zarr_store import MotionStore

    return MotionStore(config_or_fail(config).store.path)


def verify(
    config: Annotated[Path, typer.Argument(help="Config file whose store is checked.")],
) -> None:
    """Check the ``current`` pointer, the manifest it names and every object of that generation
    against their checksums; exit 1 when any is missing or damaged (``motionweb index`` repairs
    the pointer and recomputes the objects)."""
    from motionweb.flows.cli import fail
    from motionweb.store.generations import PointerError, check_current, load_generation, verify_generation
    from motionweb.store.zarr_store import StoreError

    store = _store(config)
    try:
        gen_id = check_current(store)
        gen = load_generation(store, gen_id) if gen_id else None
    except PointerError as exc:
        fail(f"damaged: {exc}", code=1)
    except StoreError as exc:
        fail(str(exc), code=1)
    if gen is None:
        fail(f"store {store.url} was never indexed (no committed generation)")
    problems = verify_generation(store, gen)
    n = len(gen.webs) + sum(len(set(r.values())) for r in gen.features.values())
    for p in problems:
        typer.echo(f"damaged: {p}")
    typer.echo(f"generation {gen.id}: {n} objects checked, {len(problems)} missing or damaged")
    if problems:
        raise typer.Exit(1)


def gc(
    config: Annotated[Path, typer.Argument(help="Config file whose store is cleaned.")],
    keep: Annotated[int, typer.Option(min=1, help="Generations kept: the current one and those before it.")] = 3,
) -> None:
    """Remove old generations, leftovers of killed runs and objects no kept generation lists.
    Do not run it while an index run writes to the same store; a store whose pointer is damaged
    is left alone (exit 1) until ``motionweb index`` repairs it."""
    from motionweb.flows.cli import fail
    from motionweb.store.generations import PointerError
    from motionweb.store.generations import gc as store_gc

    store = _store(config)
    before = store.size_bytes()
    try:
        removed = store_gc(store, keep)
    except PointerError as exc:
        fail(f"nothing removed: {exc}", code=1)
    typer.echo(f"removed {len(removed)} objects and files; store {before / 1e6:.2f} MB -> "
               f"{store.size_bytes() / 1e6:.2f} MB")
