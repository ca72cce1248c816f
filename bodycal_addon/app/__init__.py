"""Entry points (the top layer): the command line and what runs its jobs.

- `cli`: `main(argv)`, the command line of FORMATS.md §4 (`python -m bodycal_addon`); `cli_bridge`:
  the same as `blender -b -c bodycal`.
- `commands/`: one module per command, `run(args) -> exit code`, imported when its command runs.
- `batch` (`run_batch`, `load_jobs`), `cluster` (`run_on_cluster`, needs dask), `openjd` and
  `flamenco` (the batch exported for a farm); `console`: where a command's lines go.

The package re-exports nothing: `--help` loads `cli` and what it imports, no Blender and no dask."""
