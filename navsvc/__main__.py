"""``python -m navsvc``: the same as the ``navsvc`` command."""

import sys

from navsvc.cli import main

sys.exit(main())
