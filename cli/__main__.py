"""`python -m ahrsd.cli ...`: the same as the `ahrsd` console script."""

import sys

from ahrsd.cli.main import main

sys.exit(main())
