"""``python -m stiction ...`` is the ``stiction`` command."""
import sys

from .cli import main

sys.exit(main())
