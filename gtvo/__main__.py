"""``python -m gtvo`` is the same as the ``gtvo`` command."""

import sys

from gtvo.cli import main

sys.exit(main())
