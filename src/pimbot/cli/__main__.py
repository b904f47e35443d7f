"""`python -m pimbot.cli`: the `pimbot` command."""

import sys

from pimbot.cli import main

if __name__ == "__main__":
    sys.exit(main())
