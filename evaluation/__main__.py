"""``python -m evaluation`` runs ``secuav-eval``."""

import sys

from evaluation.cli import main

sys.exit(main())
