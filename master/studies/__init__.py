"""Studies of simulated participants: the power of a design to detect a contrast (``rhi power``, :mod:`.power`)."""
