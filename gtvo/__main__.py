"""``python -m gtvo`` is the same as the ``gtvo`` command."""

import sys

try:
    from gtvo.cli import entry_point
except KeyboardInterrupt:  # Ctrl-C while the command line itself is being imported
    print("gtvo: interrupted", file=sys.stderr)
    sys.exit(130)

entry_point()
