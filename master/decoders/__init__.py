"""The decoders' life cycle: the cache of trained checkpoints and the shipped ones, training and its data,
quality, and the causal model's pose encoders."""
