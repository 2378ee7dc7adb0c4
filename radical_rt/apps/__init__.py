"""Applications on the engine: the command line, the node, batch processing, the demo, maneuver design."""
