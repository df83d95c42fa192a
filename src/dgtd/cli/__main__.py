"""`python -m dgtd.cli`: the same as the `dgtd` command."""

from dgtd.cli import main

main()
