"""``python -m jsrte.cli``."""

from jsrte.cli import main

main()
