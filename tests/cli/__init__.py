"""CLI tests (a package, so that its file names may repeat those of other test folders)."""
