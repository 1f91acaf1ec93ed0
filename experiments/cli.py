"""The ``pmspm`` command line."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

os.environ.setdefault("MUJOCO_GL", "egl")  # before anything imports mujoco

OutOption = Annotated[Path, typer.Option(help="Folder for the report.")]

app = typer.Typer(
    help="Closed-loop co-design toolkit for a vision-measured spherical motor.",
    no_args_is_help=True,
    add_completion=False,
)


@app.command()
def study(out: OutOption = Path("runs")) -> None:
    """The headline study. For now a PLACEHOLDER: runs the plant demo (see `pmspm demo`).

    Example: pmspm study --out runs
    """
    typer.secho(
        "pmspm study: the headline study (issue 6) has not landed; running the plant demo "
        "as a placeholder.",
        fg=typer.colors.YELLOW,
    )
    demo(out)


@app.command()
def demo(out: OutOption = Path("runs")) -> None:
    """Tilt step of the simulated motor under a PD law on the true state, with rendered frames.

    Example: pmspm demo --out runs
    """
    from experiments.demo import run_demo

    folder = run_demo(out)
    typer.echo(f"report: {folder / 'report.md'}")


if __name__ == "__main__":
    app()
