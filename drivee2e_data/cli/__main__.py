"""`python -m drivee2e_data.cli`: the `drivee2e` command."""

import sys

from drivee2e_data.cli import main

sys.exit(main())
