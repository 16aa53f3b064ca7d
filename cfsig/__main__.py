"""Run the command line with ``python -m cfsig``."""

from .cli import main

main()
