"""`python -m lmjx.cli`: the `lmjx` command."""

from lmjx.cli import entry

entry()
