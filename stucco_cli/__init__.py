"""The `stucco` command line: a thin click layer over :mod:`pipeline`."""
