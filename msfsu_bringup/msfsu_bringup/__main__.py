import sys

from msfsu_bringup.launcher import main

sys.exit(main())
