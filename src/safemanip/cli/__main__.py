import sys

from safemanip.cli import main

sys.exit(main())
