"""The `umf` command line (typer), grouped by task."""
