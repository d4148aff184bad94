"""Command-line tools. Each module has ``main(argv=None) -> int``; heavy imports are deferred."""
