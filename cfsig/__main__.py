"""Run the command line with ``python -m cfsig``."""

from cfsig.cli import run

run()
