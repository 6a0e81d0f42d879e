import sys

from coster_sumo.cli.command_line import main

sys.exit(main())
