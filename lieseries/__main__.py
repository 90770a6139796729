"""``python -m lieseries ...``: the command line (:mod:`lieseries.cli`), for when the console script is not on PATH."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
