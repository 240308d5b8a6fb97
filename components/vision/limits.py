"""The decoder's parameter range, in a module of its own: the configuration checks it before torch loads."""

MIN_VISUAL_VARIANCE = 1e-12  # the decoder's visual_variance range: [MIN_VISUAL_VARIANCE, None]
