"""Subcommands of the ``gtvo`` CLI, one module each (see :mod:`gtvo.cli`)."""
