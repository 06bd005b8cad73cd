"""Project-wide checks: the layers, the linters, the docs' transcripts, the rooms' size, the dependencies."""
