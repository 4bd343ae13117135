"""``python -m tfl_mav.cli``: the ``tfl-mav`` command without its console script."""

import sys

from tfl_mav.cli.main import main

sys.exit(main())
