"""The figures `ahrsd calibrate ... --plot FILE.png` draws (matplotlib, the `ahrsd[plot]` extra): imported only by
the CLI, never on the daemon's path."""
