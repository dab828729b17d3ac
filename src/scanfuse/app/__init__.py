"""Applications built on the library: the demo (the CLI is `scanfuse.cli`)."""
