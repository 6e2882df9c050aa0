"""Entry point of the `umf` command: subcommand groups and one-line error handling."""

from __future__ import annotations

import sys

import typer

from umf import __version__
from umf.cli.data import app as data_app
from umf.cli.eval import evaluate
from umf.cli.generate import generate, react
from umf.cli.serve import serve, view
from umf.cli.train import app as train_app
from umf.errors import UMFError

app = typer.Typer(
    name="umf",
    help="Unified Motion Flow: text + number of people -> synchronized 3-D motion.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
app.add_typer(data_app, name="data")
app.add_typer(train_app, name="train")
app.command("generate")(generate)
app.command("react")(react)
app.command("eval")(evaluate)
app.command("serve")(serve)
app.command("view")(view)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"umf {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Unified Motion Flow: text + number of people -> synchronized 3-D motion."""


def run() -> None:
    """Console-script entry: user errors become one line on stderr and exit code 1."""
    try:
        app()
    except UMFError as exc:
        print(f"umf: error: {exc}", file=sys.stderr)
        sys.exit(1)
    except KeyboardInterrupt:
        print("umf: interrupted", file=sys.stderr)
        sys.exit(130)


if __name__ == "__main__":
    run()
