"""The ``quash`` command line. Each subcommand lives in a ``cmd_*.py`` module."""
