"""The contract's conventions, flags, state layout, parameter tables and geometry (no kernels of the filter)."""
