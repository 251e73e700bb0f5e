"""ahrsd.core: what every part shares and nothing else (CONTRIBUTING.md).

The sample and estimate types that flow between the parts, the GNSS fix, the one WMM2025 lookup, and the
angle/frame helpers. core imports numpy, scipy and pygeomag only, never another ahrsd package.
"""
