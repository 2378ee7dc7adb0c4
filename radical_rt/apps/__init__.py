"""Applications on the engine: the command line, the node, batch processing."""
