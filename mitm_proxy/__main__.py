"""``python -m mitm_proxy`` is ``secuav-proxy``."""

import sys

from mitm_proxy.cli import main

sys.exit(main())
