"""The contract's conventions, flags, state layout, parameter tables, geometry and message schemas
(no kernels of the filter)."""
