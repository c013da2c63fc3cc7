"""``python -m tactilesnn.service MODEL``: the service without torch installed."""

import sys

from .command import main

sys.exit(main())
