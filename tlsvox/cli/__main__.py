"""``python -m tlsvox.cli``: the ``tlsvox`` command."""

import sys

from tlsvox.cli.app import main

sys.exit(main())
