"""Tools around the product: the command line and offline tools (replay, monitor, evaluate)."""
