"""``python -m sionna_mmir``: the ``sionna-mmir`` command line."""
import sys

from .cli.main import main

sys.exit(main())
