"""Launcher of `msfsu-revision-change` (msfsu_evaluation.reports.revision_change) under the name its pages give."""

import sys

from msfsu_evaluation.reports.revision_change import main

sys.exit(main())
