"""The ``lhf`` command line: one parser, thin commands that call importable functions."""
