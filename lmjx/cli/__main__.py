"""`python -m lmjx.cli`: the `lmjx` command."""

import sys

from . import main

sys.exit(main())
