"""ahrsd.cli: the `ahrsd` command line — argument parsing and printing, one module per subcommand."""
