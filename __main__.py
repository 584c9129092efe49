"""``python -m mogaface …``: the command line (see ``core/cli``)."""

import sys

try:
    from .core.cli import main
except KeyboardInterrupt:  # Ctrl-C while the interpreter is still starting up
    sys.exit(130)

sys.exit(main())
