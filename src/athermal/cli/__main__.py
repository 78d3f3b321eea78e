"""``python -m athermal.cli``: the ``athermal`` command."""

import sys

from . import main

sys.exit(main())
