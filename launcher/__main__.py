"""``python -m jara_arm.launcher`` is the ``jara-arm`` command."""

import sys

from .cli import main

sys.exit(main())
