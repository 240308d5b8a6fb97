"""``python -m rhi`` is the ``rhi`` command."""
import sys

from rhi.master.commands.cli import main

sys.exit(main())
