"""``python -m mogaface …``: the command line (see ``core/cli``).

``--help`` (of the program or of any command) is answered before torch or numba is imported.
"""

import os
import signal
import sys


def _terminated_while_starting(number, frame):  # nothing is written yet: leave at once, saying so
    os.write(2, f"terminated by {signal.Signals(number).name}\n".encode())
    os._exit(128 + number)


signal.signal(signal.SIGTERM, _terminated_while_starting)  # core/cli's main() takes over from here
# Ctrl-C (and the Blender worker's cancel, a SIGINT) stops every command. A child of a script's
# background job inherits SIGINT ignored, and Python then installs no handler: a SIGINT before the
# trainer's own handler would be lost, and a cancelled run would train on.
signal.signal(signal.SIGINT, signal.default_int_handler)

# ``python -m`` puts the working directory first on sys.path. This package is imported by now,
# so nothing else may come from there (a stray numpy.py beside a capture would shadow numpy).
# Workers run with -I instead (core/for_blender/worker.py), where the entry is absent.
if sys.path and sys.path[0] in ("", os.getcwd()) and not (sys.flags.isolated or getattr(sys.flags, "safe_path", 0)):
    del sys.path[0]

try:
    from .core.cli import main
    from .core.cli.exits import leave
except KeyboardInterrupt:  # Ctrl-C while the interpreter is still starting up
    sys.exit(130)

# Leave with the signal handlers in place: the interpreter's own exit drops them before its
# tear-down (a SIGTERM then died silently with -15), and a Ctrl-C that landed in Python code an
# extension ran during start-up leaves it marked as killed by SIGINT (status -2 instead of 130).
# (--help and usage errors leave by argparse's SystemExit, before torch or numba is imported.)
leave(main())
