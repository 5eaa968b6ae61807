"""The ``motionweb`` command line (typer). Each command is a thin shell over a flow or stage."""

from __future__ import annotations

import typer

app = typer.Typer(
    name="motionweb",
    help="Search, blend and retime motion-capture libraries (KG04, HDP07, MPS06).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def fail(message: str, code: int = 2) -> None:
    """Print a clear error (never a traceback) and exit non-zero."""
    typer.secho(f"error: {message}", err=True, fg=typer.colors.RED)
    raise typer.Exit(code)


if __name__ == "__main__":
    app()
