"""``python -m attack_profiles`` is ``secuav-attack``."""

import sys

from attack_profiles.cli import main

sys.exit(main())
