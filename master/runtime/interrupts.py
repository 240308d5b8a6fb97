"""How rhi names the signals that stop a run (the command line turns SIGINT and SIGTERM into these)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: the same clean-up, exit status 143."""
