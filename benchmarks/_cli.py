"""``guidance`` as a script (for ``python -m cProfile benchmarks/_cli.py ...``)."""

import sys

from guidance.tools.cli import main

sys.exit(main())
