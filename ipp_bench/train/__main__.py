"""``python -m ipp_bench.train``: the same as ``ipp-bench train``."""

import sys

from ipp_bench.train.command import main

sys.exit(main())
