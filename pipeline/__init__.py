"""Fitting pipelines and the ``jnr`` command line. Uses every other package."""
