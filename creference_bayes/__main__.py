"""``python -m creference_bayes``: the ``creference`` command."""

import sys

from .cli import main

sys.exit(main())
