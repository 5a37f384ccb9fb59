"""Launcher of `msfsu-graph-change` (msfsu_evaluation.reports.graph_change) under the name its pages give."""

import sys

from msfsu_evaluation.reports.graph_change import main

sys.exit(main())
