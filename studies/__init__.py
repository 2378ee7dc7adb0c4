"""Engine studies that regenerate the tables in docs/: Monte Carlo consistency, warm versus cold
start, fault detection. They run the engine itself (unlike monitors/, which only read its
messages and archives). Each module is runnable: ``python -m studies.<name> --help``."""
