"""One module per command of FORMATS.md §4, each with `run(args) -> exit code`: `calibrate_user`,
`calibrate_avatar`, `retarget`, `transfer`, `batch`, `review`, `demo`, `record`, `stream`, `live`.
`cli._handler` imports a command's module only when that command runs; a module loads Blender's
glue (`bodycal_addon.blender`) inside `run`, so every module imports without Blender."""
