"""The figures `ahrsd calibrate ... --plot FILE.png` draws (matplotlib, the `plot` extra): imported only by
the CLI, never on the daemon's path."""
