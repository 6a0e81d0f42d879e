import sys

from coster_sumo.cli import main

sys.exit(main())
