"""The `rhi` command line: one module per command, argument parsing and printing only; nothing imports them."""
