"""`python -m ahrsd.cli ...`: the same as the `ahrsd` console script."""

from ahrsd.cli.main import console_main

console_main()
