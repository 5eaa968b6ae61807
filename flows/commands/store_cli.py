"""``motionweb verify`` and ``motionweb gc``: integrity and housekeeping of a config's store (design §9)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer


def verify(
    config: Annotated[Path, typer.Argument(help="Config file whose store is checked.")],
) -> None:
    """Check the ``current`` pointer, the manifest it names and every object of that generation
    against their checksums; exit 1 when any is missing or damaged (``motionweb index`` repairs
    the pointer and recomputes the objects)."""
    from motionweb.flows.commands.cli import config_or_fail, run_command
    from motionweb.flows.commands.reported import CommandError
    from motionweb.store.generations import PointerError, current_generation, verify_generation
    from motionweb.store.zarr_store import MotionStore, StoreError

    cfg = config_or_fail(config)

    def work() -> dict[str, Any]:
        store = MotionStore(cfg.store.path)
        try:
            gen = current_generation(store, strict=True)
        except PointerError as exc:
            raise CommandError(f"damaged: {exc}", exit_code=1) from None
        except StoreError as exc:
            raise CommandError(str(exc), exit_code=1) from None
        if gen is None:
            raise CommandError(f"store {store.url} was never indexed (no committed generation)")
        problems = verify_generation(store, gen)
        n = len(gen.webs) + sum(len(set(r.values())) for r in gen.features.values())
        return {"generation": gen.id, "checked": n, "problems": problems}

    def show(r: dict[str, Any]) -> None:
        for p in r["problems"]:
            typer.echo(f"damaged: {p}")
        typer.echo(f"generation {r['generation']}: {r['checked']} objects checked, {len(r['problems'])} "
                   "missing or damaged")

    res = run_command("verify", {"config": str(config)}, work, show)
    if res["problems"]:
        raise typer.Exit(1)


def gc(
    config: Annotated[Path, typer.Argument(help="Config file whose store is cleaned.")],
    keep: Annotated[int | None, typer.Option(
        help="Generations kept: the current one and those before it (default: the config's "
             "index.keep_generations).")] = None,
) -> None:
    """Remove old generations, leftovers of killed runs and objects no kept generation lists.
    Do not run it while an index run writes to the same store; a store whose pointer is damaged
    is left alone (exit 1) until ``motionweb index`` repairs it."""
    from motionweb.flows.commands.cli import config_or_fail, request_or_fail, run_command
    from motionweb.flows.commands.reported import CommandError
    from motionweb.flows.commands.requests import GcRequest
    from motionweb.store.generations import PointerError
    from motionweb.store.generations import gc as store_gc
    from motionweb.store.zarr_store import MotionStore

    request = request_or_fail(GcRequest, keep=keep)
    cfg = config_or_fail(config)

    def work() -> dict[str, Any]:
        store = MotionStore(cfg.store.path)
        before = store.size_bytes()
        try:
            removed = store_gc(store, request.keep or cfg.index.keep_generations)
        except PointerError as exc:
            raise CommandError(f"nothing removed: {exc}", exit_code=1) from None
        return {"removed": len(removed), "before_bytes": before, "after_bytes": store.size_bytes()}

    run_command("gc", {"config": str(config), "request": request.wire()}, work,
                lambda r: typer.echo(f"removed {r['removed']} objects and files; store {r['before_bytes'] / 1e6:.2f} MB "
                                     f"-> {r['after_bytes'] / 1e6:.2f} MB"))
