"""`python -m cli`: the `raq` command."""

import sys

from cli import main

sys.exit(main())
