"""``python -m fgloc`` is the ``fgloc`` command."""

import sys

from fgloc.cli import main

sys.exit(main())
