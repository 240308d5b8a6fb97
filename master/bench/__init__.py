"""`rhi bench`: the speed of each way to run the protocol, against a paper-style baseline."""
