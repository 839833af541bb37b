"""The version of rothe (one place: the package, checkpoints and the command line read it)."""

__version__ = "0.2.0"
