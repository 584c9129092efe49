"""``python -m mogaface …``: the command line (see ``core/cli``)."""

import os
import sys

# ``python -m`` puts the working directory first on sys.path. This package is imported by now,
# so nothing else may come from there (a stray numpy.py beside a capture would shadow numpy).
# Workers run with -I instead (core/worker.py), where the entry is absent.
if sys.path and sys.path[0] in ("", os.getcwd()) and not (sys.flags.isolated or getattr(sys.flags, "safe_path", 0)):
    del sys.path[0]

try:
    from .core.cli import main
except KeyboardInterrupt:  # Ctrl-C while the interpreter is still starting up
    sys.exit(130)

sys.exit(main())
