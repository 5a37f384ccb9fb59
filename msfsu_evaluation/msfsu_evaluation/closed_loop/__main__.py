"""`python -m msfsu_evaluation.closed_loop` = msfsu-benchmark."""

import sys

from msfsu_evaluation.closed_loop.cli import main

sys.exit(main())
