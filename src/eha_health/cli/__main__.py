"""``python -m eha_health.cli``: the same as the ``eha-health`` console script."""
import sys

from . import main

sys.exit(main())
