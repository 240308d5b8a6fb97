"""``python -m rhi.master`` is the ``rhi`` command (as is ``python -m rhi``)."""
import sys

from rhi.master.commands.cli import main

sys.exit(main())
