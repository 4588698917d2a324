"""``python -m hdrcore``: the same as the ``hdrcore`` command."""

import sys

from .cli import main

sys.exit(main())
