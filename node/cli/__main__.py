"""``python -m node.cli``: the ``ordervib`` command."""

import sys

from node.cli import main

sys.exit(main())
