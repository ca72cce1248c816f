"""One module per command of FORMATS.md §4, each with `run(args) -> exit code`."""
