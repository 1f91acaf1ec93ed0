"""Studies and the ``pmspm`` command line."""
