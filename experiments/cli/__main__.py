"""``python -m experiments.cli``: the ``pmspm`` command line."""

from experiments.cli import app

app()
