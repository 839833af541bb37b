"""The ``rothe`` command line (:mod:`rothe.cli.main`): the commands, their options, the run
session and the sweeps. Nothing outside this package imports it.
"""
