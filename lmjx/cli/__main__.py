"""`python -m lmjx.cli`: the `lmjx` command."""

import sys

from lmjx.cli import main

sys.exit(main())
