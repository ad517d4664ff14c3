"""``python -m cadbridge``: the `cadbridge` command (`cadbridge.cli.main`)."""

import sys

from cadbridge.cli import main

sys.exit(main())
