"""``python -m tfl_mav.tools.cli``: the ``tfl-mav`` command without its console script."""

import sys

from tfl_mav.tools.cli.main import main

sys.exit(main())
