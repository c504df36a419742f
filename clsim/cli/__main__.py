"""``python -m clsim.cli``: the ``clsim`` command."""

import sys

from clsim.cli.app import main

sys.exit(main())
