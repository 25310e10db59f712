"""`python -m smorphi_rl.cli`: the same as the `smorphi-rl` command."""

import sys

from smorphi_rl.entry import main

sys.exit(main())
