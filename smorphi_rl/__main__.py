"""`python -m smorphi_rl`: the same as the `smorphi-rl` command (and `python -m smorphi_rl.cli`)."""

import sys

from smorphi_rl.entry import main

sys.exit(main())
