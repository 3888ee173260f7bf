"""``python -m clothfit ...``: the headless CLI, the same program as the ``clothfit`` console script."""

import sys

from .cli import main

sys.exit(main())
