import sys

from webconsole.cli import main

sys.exit(main())
