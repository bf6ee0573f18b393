"""`python -m drivee2e_data.cli`: the `drivee2e` command, through its entry point."""

import sys

from drivee2e_data.launch import main

sys.exit(main())
