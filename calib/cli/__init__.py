"""The ``gyrocal`` command line."""
