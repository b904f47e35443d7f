"""`python -m pimbot.cli`: the `pimbot` command."""

import sys

from pimbot.cli import main

sys.exit(main())
