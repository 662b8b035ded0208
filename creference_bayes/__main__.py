"""``python -m creference_bayes``: the ``creference`` command."""

import sys

from .cli.main import main

sys.exit(main())
