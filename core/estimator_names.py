"""The estimators' names, which the command line and the configuration check offer before any estimator is
built: here, not only in ahrsd.estimator, because importing that package loads numpy and digests the kernels'
sources (estimator/kernel_cache.py), which `ahrsd --help`, the `ahrsd` commands that run no estimator and every
process multiprocessing spawns from the `ahrsd` script (it imports the script's module again, ahrsd.cli.main)
would pay for a tuple of strings."""

from __future__ import annotations

ESTIMATORS = ("mekf", "thesis", "ins")
